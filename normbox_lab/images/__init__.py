"""Spectral images: the virtual camera (the Normbox paper's Fig. 1), MIST techniques (wavelength
triplets in an RGB renderer, metameric spectra from sRGB, spectral → sRGB, multilayer OpenEXR)
and the Wilkie–Weidlich illumination estimate for white-balanced previews.

Modules (heavy libraries imported lazily inside functions):
    color        spectral images → XYZ → sRGB, ΔE00 maps (colour-science)
    camera       band-vector camera tracer: spectral image + components, depth, normal, CWNI/NWCI
    triplet      MIST wavelength-triplet rendering in Mitsuba's RGB variant (cross-check)
    metamer      metameric reflectance spectra for sRGB colours (KD-tree over colour-science data)
    exr          multilayer spectral OpenEXR export
    whitebalance Wilkie & Weidlich 2009 illumination estimate + Bradford adaptation
"""
