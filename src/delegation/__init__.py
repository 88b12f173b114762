"""Delegation service for WARA-PS: allocates live units to partially specified TSTs."""

__version__ = "0.1.0"
