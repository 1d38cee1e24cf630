"""hadal: post-dive processing for deep-sea vehicles (Prefect-free science and I/O library)."""

__version__ = "0.1.0"
