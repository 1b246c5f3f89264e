"""real2sim: turn a real object into a dynamically accurate, fast simulation asset, and measure both."""

__version__ = "0.1.0"
