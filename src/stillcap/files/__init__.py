"""Plain file helpers at the bottom of the stack: atomic writes, JSON, paths kept inside a folder,
NumPy values as JSON, typed validation of user files (``schema``), and the one reader of photos
(``images``: size and completeness checked before OpenCV decodes). Nothing here imports any
other part of stillcap."""
