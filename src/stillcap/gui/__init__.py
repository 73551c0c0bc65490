"""The browser GUI (``stillcap gui``): a local Starlette application serving the puppet workflow
and the pitch and hand viewers (issue 13; ``docs/gui.md``)."""
