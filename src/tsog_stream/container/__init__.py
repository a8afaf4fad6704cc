"""The ``.tsogs`` stream container: one static file of TSOG chunks, addressed by byte ranges.

Sans-I/O format code (``header``, ``index``) plus a reader that runs on any byte source.
"""
