"""The ``.tsogs`` stream container: one static file of TSOG chunks, addressed by byte ranges.

The format, sans-I/O (``header``, ``index``, ``ranges``, ``stream_index``: bytes in, checked
values out), plus the byte sources a reader runs on (``sources``) and the writer (``writer``).
Reading a container is :mod:`tsog_stream.client`'s job.
"""
