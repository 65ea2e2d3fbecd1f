"""vtexp: a psychophysics experiment runner for tactile shape displays.

The package turns declared experiments (YAML) into trials, drives a tactile
array through a device backend, asks a participant, and logs every trial so
that a crash loses nothing. See docs/architecture.md for the layers.
"""

__version__ = "0.1.0"
