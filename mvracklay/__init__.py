"""MVRackLay toolkit: the command-line application and end-to-end pipeline."""

__version__ = "0.1.0"
