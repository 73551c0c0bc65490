"""Plain file helpers at the bottom of the stack: atomic writes, JSON, paths kept inside a folder,
NumPy values as JSON. Nothing here imports any other part of stillcap."""
