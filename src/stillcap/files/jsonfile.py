"""Reading the JSON files stillcap and its users write (rigs, skeletons, captures, projects)."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path


def read_json(path, what: str = ""):
    """Parsed content of a UTF-8 JSON file.

    A missing file or invalid JSON raises ``ValueError`` naming the file (prefixed by ``what``,
    e.g. ``"rig file"``), so that the CLI reports it in one line.
    """
    path = Path(path)
    name = f"{what} {path}" if what else str(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"{name} does not exist") from None
    except IsADirectoryError:
        raise ValueError(f"{name} is a folder, not a JSON file") from None
    except OSError as e:
        raise ValueError(f"{name} cannot be read: {e.strerror or e}") from None
    except RecursionError:
        raise ValueError(f"{name} is not valid JSON: nested too deeply") from None
    except ValueError as e:  # JSONDecodeError, UnicodeDecodeError, an integer of more than 4300 digits
        raise ValueError(f"{name} is not valid JSON: {e}") from None


def read_package_json(name: str) -> tuple[dict, str]:
    """A JSON file shipped in ``stillcap/data`` (default skeletons and marker sets): its content
    and the source name models record (``stillcap/data/NAME``)."""
    # the file itself where the package is a folder on disk (any ordinary install): the first
    # importlib.resources.files() of a process costs ~0.6 ms CPU (its readers' set-up), a share
    # of the puppet pipeline's first call; resources for any other kind of install (a zip)
    here = Path(__file__).parent.parent / "data" / name
    if here.is_file():
        text = here.read_text(encoding="utf-8")
    else:
        text = resources.files("stillcap").joinpath("data", name).read_text(encoding="utf-8")
    return json.loads(text), f"stillcap/data/{name}"
