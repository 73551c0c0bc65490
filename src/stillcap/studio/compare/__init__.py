"""Results against the studio's truth: the one place truth files are read and compared.

One module per kind of capture. The demo, the benchmarks and the CLI call these when a capture
folder holds a ``truth`` (the studio writes it); the pipelines never see a truth.
"""
