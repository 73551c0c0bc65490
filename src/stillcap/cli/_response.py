"""The ``--response`` option shared by ``stillcap pitch``, ``hand``, ``puppet run`` and ``markers``."""

from __future__ import annotations

RESPONSE_HELP = ("The cameras' response (how pixel values relate to light): auto (estimated from the photos, "
                 "reported), srgb, linear or gamma:G. Default: each camera's 'response' in the rig "
                 "(srgb when the rig does not say). See docs/camera-response.md.")


def parse_response_option(text: str | None):
    """``None`` (the rig's), ``"auto"`` or a :class:`stillcap.response.Response`; ValueError (exit
    status 2) naming a bad spec. Imports NumPy only when the option is given."""
    if text is None:
        return None
    from stillcap.response import parse_response_spec

    return parse_response_spec(text)
