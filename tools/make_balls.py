"""Generates src/stillcap/data/balls/*.json (baseball: the seed layout; softball, cricket, tennis: designed). Made the shipped files with the design module of commit ddb9001 (near rotations restricted to type-matched pairs); rerunning with today's module may assign other types."""
import json, math, sys
import numpy as np
from stillcap.ball.layout import _SEED_MARKERS, DEFAULT_PALETTE, DEFAULT_MARKER_SIZE, TYPE_NAMES, TYPE_SHAPES, BallLayout, check_layout
from stillcap.ball.design import design_layout, score_layout
from stillcap.ball.ballfile import Ball

out = "src/stillcap/data/balls"
def types_block(names, shapes, pal, size_deg):
    return [{"name": n, "shape": s, "color_linear": list(pal[n]), "size_deg": size_deg} for n, s in zip(names, shapes)]

base = {"format": "stillcap-ball", "version": 1, "name": "baseball",
        "description": "The seed's painted baseball: 12 markers of 4 types (8 on the equator in pairs, 4 on the orthogonal great circle 30 deg from the poles); docs/spin.md.",
        "radius_m": 0.03685, "mass_kg": 0.145, "flight": "baseball",
        "types": types_block(TYPE_NAMES, TYPE_SHAPES, DEFAULT_PALETTE, math.degrees(DEFAULT_MARKER_SIZE)),
        "markers": [{"type": TYPE_NAMES[t], "azimuth_deg": a, "polar_deg": p} for a, p, t in _SEED_MARKERS]}
json.dump(base, open(f"{out}/baseball.json", "w"), indent=1); open(f"{out}/baseball.json", "a").write("\n")

specs = [  # name, n, radius, mass, flight, type names, shapes, palette, size_deg, description, seed
 ("softball", 16, 0.0485, 0.184, "softball", ("red", "blue", "green", "black"), ("square", "ring", "triangle", "disc"),
  DEFAULT_PALETTE, 7.0, "A white fastpitch softball (12 in) painted with 16 markers of 4 types, designed by `stillcap balls design 16` (spread positions, types chosen for separation)."),
 ("cricket", 12, 0.03595, 0.160, "cricket", ("magenta", "blue", "green", "black"), ("disc", "square", "ring", "triangle"),
  {"magenta": (0.70, 0.04, 0.60), "blue": (0.03, 0.10, 0.80), "green": (0.05, 0.60, 0.06), "black": (0.02, 0.02, 0.02)}, 9.0,
  "A white cricket ball painted with 12 markers of 4 types (magenta disc, blue square, green ring, black triangle), designed by `stillcap balls design 12`."),
 ("tennis", 12, 0.0335, 0.0577, "tennis", ("red", "blue", "green", "black"), ("ring", "triangle", "disc", "square"),
  DEFAULT_PALETTE, 9.5, "A white tennis ball painted with 12 markers of 4 types (red ring, blue triangle, green disc, black square), designed by `stillcap balls design 12`."),
]
for name, n, r, m, fl, names, shapes, pal, size, desc in specs:
    tpl = BallLayout(np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0]], float), np.arange(4), names, shapes,
                     {k: pal[k] for k in names}, marker_size=math.radians(size), radius=r, name=name)
    lay, sc = design_layout(n, 4, template=tpl, rng={"softball": 1, "cricket": 2, "tennis": 3}[name], restarts=6, sweeps=3)
    d = {"format": "stillcap-ball", "version": 1, "name": name, "description": desc, "radius_m": r, "mass_kg": m,
         "flight": fl, "types": types_block(names, shapes, pal, size),
         "markers": [{"type": names[t], "azimuth_deg": round(math.degrees(math.atan2(v[1], v[0])) % 360, 2),
                      "polar_deg": round(math.degrees(math.acos(np.clip(v[2], -1, 1))), 2)} for v, t in zip(lay.directions, lay.types)]}
    path = f"{out}/{name}.json"
    json.dump(d, open(path, "w"), indent=1); open(path, "a").write("\n")
    b = Ball.load(path)
    for mg in (0, 10, 15):
        c = check_layout(b.layout, mg); s = score_layout(b.layout, mg)
        print(name, mg, "exact: ambiguous", c.n_ambiguous, "minsep %.1f" % c.min_separation_deg, "3types %.3f" % c.share_3_types, "| near:", "det %.3f minsep %.1f" % (s.share_determined, s.min_separation_deg))
