"""Prediction: the Normbox scene, materials, BRDF model, Mitsuba rendering, the fast band-vector renderer and executors."""
