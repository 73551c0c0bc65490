"""What every GUI route sees: the opened folder, the session token and the confined resolver.

The application (:mod:`stillcap.gui.app`) builds one :class:`GuiContext` per server; the route
modules (``gui/puppet.py``, ``gui/pitch.py``, ``gui/hand.py``) each expose
``routes(ctx: GuiContext) -> list[starlette.routing.BaseRoute]``, mounted under ``/api/<name>``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stillcap.files.paths import resolve_inside

__all__ = ["GuiContext"]


@dataclass
class GuiContext:
    """The opened project or capture folder and the session's secrets.

    Attributes
    ----------
    root : Path
        The folder the GUI may read and write (a puppet project, a capture folder, a session of
        captures). Nothing outside it is served or written.
    token : str
        The per-session token every request must carry.
    state : dict
        Per-server state the route modules keep (jobs, caches), keyed by module.
    """

    root: Path
    token: str
    state: dict[str, Any] = field(default_factory=dict)

    def resolve(self, relative: str) -> Path:
        """``root / relative``, refused with ``ValueError`` when it leaves ``root``."""
        return resolve_inside(self.root, relative, "", "opened folder")
