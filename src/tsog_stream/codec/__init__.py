"""SOG v2 and TSOG chunk codec: Gaussians <-> index-aligned images + meta.json (sans-I/O)."""
