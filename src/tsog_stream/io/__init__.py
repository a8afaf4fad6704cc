"""Readers and writers of splat files (sans-I/O parsers with thin file wrappers)."""
