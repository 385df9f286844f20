"""The opalflow version (one place; ``opalflow.__version__`` re-exports it)."""
__version__ = "0.1.0"
