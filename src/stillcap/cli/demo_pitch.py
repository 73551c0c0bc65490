"""`stillcap demo pitch`: render one pitch, analyse it, compare with the truth, write the report.

The lead wires :func:`pitch_demo` into ``stillcap demo`` (``cli/demo.py``).
"""

from __future__ import annotations

from pathlib import Path

from rich.console import Console
from rich.table import Table

from stillcap.cli._format import num as _f
from stillcap.cli._progress import progress

console = Console()

#: The seed's Table 1 (SPEC J1), per preset of the pitch studio.
SEED_TABLE1 = {
    "seed-2seam": (18, 39, 1.3, 1.9, 0.4, 22, 63.2, 1596),
    "seed-4seam": (18, 41, 2.5, 0.8, 0.1, 17, 64.2, 1612),
    "seed-curveball": (19, 39, 0.7, 1.4, 0.3, 7, 61.9, 1623),
    "seed-slider": (15, 25, 3.8, 0.7, 0.4, 13, 65.7, 1491),
    "seed-changeup": (13, 35, 1.4, 1.1, 0.3, 32, 60.6, 1258),
}


def pitch_demo(out: Path, seed: int, *, preset: str = "seed-4seam", calibrate: bool = True,
               image_size=(2560, 1920), spin_method: str = "global", physics: str | None = None):
    """Render a pitch with the studio, analyse it with the pitch pipeline, print the seed's
    Table 1 measured against the truth and the metrics with their 1-sigma, write the report.

    Parameters
    ----------
    out : Path
        Folder for ``capture/`` (the rendered capture folder) and ``report/`` (report.html,
        pitch.json, positions.csv, metrics.csv, plots).
    seed : int
        Random seed of the pitch and the photos.
    preset : str
        Studio pitch preset (``stillcap studio pitch --list-presets``).
    calibrate : bool
        Calibrate the rig from rendered board photos (realistic, ~1 min) or use the true rig.
    image_size : (width, height)
    spin_method : {"global", "seed"}
    physics : {"seed", "nathan"}, optional
        Default: the model the studio rendered with.

    Returns
    -------
    PitchResult
    """
    from stillcap.io.capture import Capture
    from stillcap.pipelines.pitch import TABLE1_COLUMNS, PitchOptions, analyse_pitch
    from stillcap.report.pitch import write_report
    from stillcap.studio.compare.pitch import add_truth_comparison
    from stillcap.studio.pitch import pitch_capture

    out = Path(out)
    console.rule(f"[bold]stillcap demo: a {preset} pitch photographed by two strobed stereo pairs")
    with progress("pitch demo: rendering") as bar:
        pc = pitch_capture(preset, seed, calibrate=calibrate, image_size=image_size, progress=bar)
        bar.stage("pitch demo: writing the capture")
        cap, images = pc.to_capture()
        cap.save(out / "capture", images)
        truth = pc.truth
        release_y_ft = truth.metrics.get("release_pos_y_ft")
        opts = PitchOptions(spin_method=spin_method, physics=physics or truth.model, release_y_ft=release_y_ft)
        bar.stage("pitch demo: analysing")
        loaded = Capture.load(out / "capture")
        res = analyse_pitch(loaded, opts, progress=bar)
        bar.stage("pitch demo: comparing with the truth")
        add_truth_comparison(res, loaded.truth)
    rel = truth.release
    console.print(f"true pitch: {rel.speed_mph:.1f} mph, {rel.spin_rpm:.0f} rpm, {truth.metrics.get('spin_tilt')}; rig "
                  + ("calibrated from rendered board photos" if calibrate else "true (not calibrated)")
                  + f"; release evaluated at the true release plane y = {release_y_ft:.2f} ft "
                  "(the photos do not show the hand)")
    for m in res.messages:
        console.print(f"[yellow]note:[/] {m}", highlight=False)
    tc = res.truth or {}
    t = Table(title="Seed Table 1: the reference trajectory against the truth, against the measured initial "
              "parameters (as the seed did), and the seed paper's row (real photos)")
    t.add_column("column", no_wrap=True)
    t.add_column("vs truth", justify="right")
    t.add_column("vs measured", justify="right")
    if preset in SEED_TABLE1:
        t.add_column("seed paper", justify="right")
    row = tc.get("table1", {})
    for i, (c, unit) in enumerate(TABLE1_COLUMNS):
        cells = [c, _f(row.get(c), 3), _f(res.table1.get(c), 3)]
        if preset in SEED_TABLE1:
            cells.append(_f(SEED_TABLE1[preset][i], 1))
        t.add_row(*cells)
    console.print(t)
    mt = Table(title="Pitch metrics: measured ± 1 sigma vs truth")
    for c in ("metric", "measured", "± sigma", "truth", "error"):
        mt.add_column(c, justify="right")
    for k, d in (tc.get("metrics") or {}).items():
        mt.add_row(k, _f(d["ours"], 3), _f(d["sigma"], 3), _f(d["truth"], 3), _f(d["diff"], 3))
    mt.add_row("spin_tilt", str(res.metrics.spin_tilt or "-"), "", str(truth.metrics.get("spin_tilt")), "")
    console.print(mt)
    offs = tc.get("time_offsets") or {}
    for name, o in offs.items():
        console.print(f"clock offset of pair {name}: {o['fitted_s'] * 1e3:.3f} ms, error {o['error_ms']:+.3f} ms "
                      f"(1 sigma {o['sigma_ms']:.3f} ms)")
    with progress("pitch demo: writing the report"):
        paths = write_report(res, out / "report")
    console.print("time: " + ", ".join(f"{k} {v:.2f} s" for k, v in res.timings_s.items()))
    console.print(f"capture in [bold]{out / 'capture'}[/], report in [bold]{paths['html']}[/]")
    return res
