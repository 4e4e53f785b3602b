"""ftc-verify: design and verify fault-tolerant controllers under random FDI delay."""

__version__ = "0.1.0"
