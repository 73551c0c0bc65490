"""`stillcap gui [FOLDER]`: the browser GUI on 127.0.0.1 (see docs/gui.md)."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

console = Console()


def gui(
    folder: Path = typer.Argument(None, help="A puppet project, a capture folder (pitch, hand, puppet), a session "
                                  "of captures, or an empty folder for new projects (default: the current folder)."),
    port: int = typer.Option(0, "--port", min=0, max=65535, help="Port on 127.0.0.1 (0: a free one)."),
    no_browser: bool = typer.Option(False, "--no-browser", help="Do not open the browser; only print the URL."),
):
    """Open the graphical application in the browser: the puppet workflow and the pitch and hand viewers.

    It serves on 127.0.0.1 only; the printed URL carries this session's token, which every
    request needs. Only files inside FOLDER are served or written.
    """
    import secrets
    import socket
    import webbrowser

    import uvicorn

    from stillcap.gui.app import create_app, folder_kind
    from stillcap.gui.context import GuiContext

    root = Path(folder if folder is not None else Path.cwd())
    if not root.exists():
        raise ValueError(f"folder {root} does not exist")
    if not root.is_dir():
        if root.name in ("project.json", "capture.json"):
            root = root.parent
        else:
            raise ValueError(f"{root} is not a folder (give a project, a capture folder or a session folder)")
    root = root.resolve()
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.bind(("127.0.0.1", port))
    except OSError as e:
        sock.close()
        raise ValueError(f"cannot listen on 127.0.0.1:{port} ({e.strerror}); choose another --port") from None
    port = sock.getsockname()[1]
    token = secrets.token_urlsafe(24)
    app = create_app(GuiContext(root, token), port=port)
    kind = folder_kind(root)
    page = {"pitch": "pitch.html", "session": "pitch.html", "hand": "hand.html"}.get(kind, "puppet.html")
    url = f"http://127.0.0.1:{port}/{page}?token={token}"
    console.print(f"stillcap gui: {root} ({kind})")
    console.print(f"open [bold]{url}[/]  (Ctrl+C stops the server)", soft_wrap=True, highlight=False)
    if not no_browser:
        webbrowser.open(url)
    config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="on")
    uvicorn.Server(config).run(sockets=[sock])
