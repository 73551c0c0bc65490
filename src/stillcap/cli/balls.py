"""`stillcap balls`: the built-in balls, one ball file shown, and a marker layout designed for N
markers (``docs/ball-format.md``)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

console = Console()
app = typer.Typer(invoke_without_command=True, add_completion=False,
                  help="Balls: list the built-in ones (no sub-command), show one, design a marker layout.")


@app.callback()
def balls(ctx: typer.Context,
          as_json: bool = typer.Option(False, "--json", help="Print the list as JSON.")):
    """List the built-in balls: name, radius, mass, flight preset, markers and their types."""
    if ctx.invoked_subcommand is not None:
        return
    from stillcap.ball.ballfile import builtin_ball, builtin_ball_names

    rows = [builtin_ball(n).summary() for n in builtin_ball_names()]
    if as_json:
        print(json.dumps(rows, indent=1))
        return
    t = Table(title=f"{len(rows)} built-in balls (stillcap pitch --ball NAME; stillcap balls show NAME)")
    for c in ("name", "radius mm", "mass g", "flight", "markers", "types (colour shape x count)"):
        t.add_column(c, justify="left" if c in ("name", "flight", "types (colour shape x count)") else "right")
    for r in rows:
        t.add_row(r["name"], f"{r['radius_mm']:.2f}", f"{r['mass_g']:.1f}", r["flight"], str(r["markers"]),
                  ", ".join(f"{ty['name']} {ty['shape']} x{ty['markers']}" for ty in r["types"]))
    console.print(t)


@app.command("show")
def show(ball: str = typer.Argument(..., help="A built-in ball's name or a ball file."),
         as_json: bool = typer.Option(False, "--json", help="Print the ball file's content (normalised: directions "
                                      "as vectors, colours linear, sizes in degrees).")):
    """One ball: its size, mass, flight, types and every marker's direction."""
    from stillcap.ball.ballfile import load_ball
    from stillcap.ball.layout import check_layout

    b = load_ball(ball, "ball")
    if as_json:
        print(json.dumps(b.to_dict(), indent=1))
        return
    s = b.summary()
    console.print(f"[bold]{b.name}[/]: radius {s['radius_mm']:.2f} mm, mass {s['mass_g']:.1f} g, flight "
                  f"{s['flight']}, {s['markers']} markers ({b.source})", highlight=False)
    if b.description:
        console.print(b.description, highlight=False)
    t = Table(title="marker types")
    for c in ("type", "shape", "colour (sRGB)", "size deg", "size mm", "markers"):
        t.add_column(c, justify="right")
    for ty in s["types"]:
        t.add_row(ty["name"], ty["shape"], f"[on {ty['color_srgb']}]    [/] {ty['color_srgb']}",
                  f"{ty['size_deg']:.2f}", f"{math.radians(ty['size_deg']) * s['radius_mm']:.2f}", str(ty["markers"]))
    console.print(t)
    lay = b.layout
    m = Table(title="markers (ball frame; azimuth from x toward y, polar angle from +z)")
    for c in ("name", "type", "azimuth deg", "polar deg"):
        m.add_column(c, justify="right")
    for n, d, k in zip(lay.names, lay.directions, lay.types):
        m.add_row(n, lay.type_names[k], f"{math.degrees(math.atan2(d[1], d[0])) % 360:.2f}",
                  f"{math.degrees(math.acos(max(-1.0, min(1.0, d[2])))):.2f}")
    console.print(m)
    for margin in (0, 10):
        c = check_layout(lay, margin)
        console.print(f"views at a {margin} deg margin: frame ambiguous from {c.n_ambiguous} of {len(c.view_dirs)}, "
                      f"smallest separation {c.min_separation_deg:.1f} deg, {100 * c.share_3_types:.1f} % see 3 "
                      f"types", highlight=False)


@app.command("design")
def design(n: int = typer.Argument(..., help="Number of markers."),
           types: int = typer.Option(4, "--types", min=1, help="Number of marker types (at most the template's)."),
           template: str = typer.Option("baseball", "--template", help="Ball (name or file) whose types (colours, "
                                        "shapes, sizes), radius, mass and flight the design takes."),
           name: str = typer.Option(None, "--name", help="Name of the designed ball (default: TEMPLATE-N)."),
           out: Path = typer.Option(None, "--out", help="Write the ball file here (atomically)."),
           seed: int = typer.Option(0, "--seed", help="Random seed of the search (same seed, same layout)."),
           restarts: int = typer.Option(6, "--restarts", min=1, help="Random type assignments tried."),
           force: bool = typer.Option(False, "--force", help="Overwrite a file stillcap did not write."),
           as_json: bool = typer.Option(False, "--json", help="Print the ball file's content.")):
    """Design a well-conditioned marker layout for N markers: positions spread evenly on the
    sphere, types assigned so that every view fixes the ball frame by the widest margin
    (docs/ball-format.md, "Designing a layout")."""
    from dataclasses import replace

    from stillcap.ball.ballfile import Ball, load_ball
    from stillcap.ball.design import design_layout, score_layout
    from stillcap.ball.layout import check_layout
    from stillcap.cli._outputs import check
    from stillcap.files.outputs import record_outputs

    if n < 2:
        raise ValueError(f"N must be at least 2 markers, got {n}")
    check(out, "file", "--out", force)
    tpl = load_ball(template, "--template")
    lay, score = design_layout(n, types, template=tpl.layout, rng=seed, restarts=restarts,
                               name=name or f"{tpl.name}-{n}")
    ball = replace(tpl, layout=lay, description=f"{n} markers of {types} types designed by `stillcap balls design "
                   f"{n} --types {types} --template {template} --seed {seed}`", source="", marker_names=())
    ball = Ball.from_dict(ball.to_dict(), "designed ball")  # the file's own checks (overlaps, colours)
    if out is not None:
        ball.save(out)
        record_outputs([out])
    if as_json:
        print(json.dumps(ball.to_dict(), indent=1))
        return
    t = Table(title=f"{n} markers of {types} types on the {tpl.name}'s {1e3 * tpl.radius:.1f} mm ball")
    for c in ("margin deg", "views", "ambiguous (exact)", "determined (near, >= 5 deg)", "smallest separation deg",
              "3 types"):
        t.add_column(c, justify="right")
    for margin in (0, 10, 15):
        c = check_layout(ball.layout, margin)
        s = score_layout(ball.layout, margin)
        t.add_row(str(margin), str(len(c.view_dirs)), str(c.n_ambiguous), f"{100 * s.share_determined:.1f} %",
                  f"{min(c.min_separation_deg, s.min_separation_deg):.1f}", f"{100 * c.share_3_types:.1f} %")
    console.print(t)
    if out is not None:
        console.print(f"wrote [bold]{out}[/]")
