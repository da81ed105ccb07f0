"""normbox-lab: acquisition, instrument control and validation for the Normbox.

Keep this module light: the CLI imports it on every start.
"""

__version__ = "0.1.0"
