"""Analysis: BRDF fitting, comparison metrics and error model, the pipeline steps and the report."""
