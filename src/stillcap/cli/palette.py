"""`stillcap palette N`: propose N maximally distinct marker colours (or N more beside kept ones)."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

console = Console()


def _kept_palette(keep: str):
    """The colours ``--keep`` names: ``puppet`` (the thesis's 16), a built-in marker set's name,
    a marker-set JSON file or a palette JSON (``{"colors": [{"name", "rgb"}]}``)."""
    from stillcap.body.markerset import BUILTIN_MARKERSETS, MarkerSet
    from stillcap.detect.palette import Palette

    if keep == "puppet":
        return Palette.from_markerset(MarkerSet.puppet())
    if keep in BUILTIN_MARKERSETS:
        return Palette.from_markerset(MarkerSet.builtin(keep))
    path = Path(keep)
    if not path.is_file():
        raise ValueError(f"--keep {keep!r} is neither 'puppet', a built-in marker set "
                         f"({', '.join(BUILTIN_MARKERSETS)}) nor an existing file")
    from stillcap.files.jsonfile import read_json

    d = read_json(path, "--keep")
    if isinstance(d, dict) and d.get("format") == "stillcap-markerset":
        return Palette.from_markerset(MarkerSet.from_dict(d, source=f"--keep {path}"))
    if not (isinstance(d, dict) and "colors" in d):
        raise ValueError(f"--keep {path}: neither a marker set (\"format\": \"stillcap-markerset\") nor a palette "
                         "({\"colors\": [{\"name\", \"rgb\"}]})")
    return Palette.from_dict(d, source=f"--keep {path}")


def palette(
    n: int = typer.Argument(..., help="Number of colours."),
    as_json: bool = typer.Option(False, "--json", help="Print the palette as JSON ({\"colors\": [...]})."),
    seed: int = typer.Option(0, "--seed", help="Random seed of the search (same seed, same palette)."),
    lightness_weight: float = typer.Option(1.0, "--lightness-weight", help="Weight of lightness differences in "
                                           "CIEDE2000; 0.5 favours colours that survive light changes."),
    restarts: int = typer.Option(8, "--restarts", min=1, help="Random starts of the search."),
    keep: str = typer.Option(None, "--keep", help="Colours that exist already: 'puppet' (the thesis's 16 beads), "
                             "a built-in marker set (puppet-20), a marker-set file or a palette JSON. The N new "
                             "colours are as far as possible from each other and from these."),
    names: str = typer.Option(None, "--names", help="Comma-separated names of the N new colours."),
    min_grey: float = typer.Option(0.0, "--min-grey", min=0.0, max=1.0,
                                   help="Smallest mean of the sRGB channels (0-1): the bead detector works on the "
                                        "grey image, where dim colours are found less often (0.48 for puppet-20)."),
):
    """Propose N maximally distinct marker colours.

    The smallest CIEDE2000 distance between the colours is maximised over bright, saturated
    colours that stay away from the black background and limbs (docs/puppet-detection.md).
    With --keep, N colours to add: the smallest distance among them and to the kept colours
    is maximised (docs/puppet.md, the puppet-20 marker set).
    """
    from stillcap.detect.palette import propose_palette

    if n < 1:
        raise ValueError(f"N must be a positive number of colours, got {n}")
    fixed = _kept_palette(keep) if keep is not None else None
    name_list = None
    if names is not None:
        name_list = [s.strip() for s in names.split(",")]
        if len(name_list) != n or not all(name_list):
            raise ValueError(f"--names must give {n} non-empty names, got {names!r}")
    prop = propose_palette(n, rng=seed, lightness_weight=lightness_weight, restarts=restarts, fixed=fixed,
                           names=name_list, min_grey=min_grey)
    if as_json:
        d = prop.palette.to_dict()
        d.update({"metric": prop.metric, "lightness_weight": prop.lightness_weight,
                  "min_distance": round(float(prop.min_distance), 4), "closest_pair": list(prop.closest_pair),
                  "min_distance_to_background": round(float(prop.min_distance_to_excluded), 4)})
        if fixed is not None:
            d.update({"kept": list(fixed.names), "min_distance_to_kept": round(float(prop.min_distance_to_fixed), 4),
                      "closest_kept_pair": list(prop.closest_fixed),
                      "guaranteed_distance": round(prop.guaranteed_distance, 4)})
        print(json.dumps(d, indent=1))
        return
    title = f"{n} marker colours (smallest CIEDE2000 distance {prop.min_distance:.2f}, " \
            f"between {prop.closest_pair[0]} and {prop.closest_pair[1]})"
    if fixed is not None:
        title = f"{n} marker colours beside {len(fixed)} kept ones (smallest CIEDE2000 distance " \
                f"{prop.guaranteed_distance:.2f}: {prop.min_distance:.2f} among the new, between " \
                f"{prop.closest_pair[0]} and {prop.closest_pair[1]}; {prop.min_distance_to_fixed:.2f} to the " \
                f"kept, between {prop.closest_fixed[0]} and {prop.closest_fixed[1]})"
    t = Table(title=title)
    for c in ("name", "colour", "hex", "R G B (0-255)", "H S B"):
        t.add_column(c, justify="right")
    pal = prop.palette
    for name, hx, rgb, hsb in zip(pal.names, pal.hex, pal.rgb, pal.hsb):
        t.add_row(name, f"[on {hx}]      [/]", hx, " ".join(f"{round(v * 255):d}" for v in rgb),
                  " ".join(f"{v:.3f}" for v in hsb))
    console.print(t)
