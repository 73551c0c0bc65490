"""`stillcap palette N`: propose N maximally distinct marker colours."""

from __future__ import annotations

import json

import typer
from rich.console import Console
from rich.table import Table

console = Console()


def palette(
    n: int = typer.Argument(..., help="Number of colours."),
    as_json: bool = typer.Option(False, "--json", help="Print the palette as JSON ({\"colors\": [...]})."),
    seed: int = typer.Option(0, "--seed", help="Random seed of the search (same seed, same palette)."),
    lightness_weight: float = typer.Option(1.0, "--lightness-weight", help="Weight of lightness differences in "
                                           "CIEDE2000; 0.5 favours colours that survive light changes."),
    restarts: int = typer.Option(8, "--restarts", min=1, help="Random starts of the search."),
):
    """Propose N maximally distinct marker colours.

    The smallest CIEDE2000 distance between the colours is maximised over bright, saturated
    colours that stay away from the black background and limbs (docs/puppet-detection.md).
    """
    from stillcap.detect.palette import propose_palette

    if n < 1:
        raise ValueError(f"N must be a positive number of colours, got {n}")
    prop = propose_palette(n, rng=seed, lightness_weight=lightness_weight, restarts=restarts)
    if as_json:
        d = prop.palette.to_dict()
        d.update({"metric": prop.metric, "lightness_weight": prop.lightness_weight,
                  "min_distance": round(float(prop.min_distance), 4), "closest_pair": list(prop.closest_pair),
                  "min_distance_to_background": round(float(prop.min_distance_to_excluded), 4)})
        print(json.dumps(d, indent=1))
        return
    t = Table(title=f"{n} marker colours (smallest CIEDE2000 distance {prop.min_distance:.2f}, "
                    f"between {prop.closest_pair[0]} and {prop.closest_pair[1]})")
    for c in ("name", "colour", "hex", "R G B (0-255)", "H S B"):
        t.add_column(c, justify="right")
    pal = prop.palette
    for name, hx, rgb, hsb in zip(pal.names, pal.hex, pal.rgb, pal.hsb):
        t.add_row(name, f"[on {hx}]      [/]", hx, " ".join(f"{round(v * 255):d}" for v in rgb),
                  " ".join(f"{v:.3f}" for v in hsb))
    console.print(t)
