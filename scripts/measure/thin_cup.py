# A closed thin-walled cup as an OBJ on stdout: a cylinder 1 across and 1 high (base at
# z = 0) hollowed from the top, its side wall and bottom WALL thick (default 0.02: 2 % of
# the diameter), the rim closed; the profile revolved in AROUND steps (default 96: 17,472
# triangles), each profile segment about as long as one step along the outer circle. The
# same surface as `cup` in crates/soft_tissue_core/tests/tetrahedralize/shapes.rs.
#
#   python3 scripts/measure/thin_cup.py [WALL [AROUND]] > cup.obj
#   soft-tissue mesh tetrahedralize cup.obj --out cup.vtu --max-distance 1
import math
import sys

R, H = 0.5, 1.0
wall = float(sys.argv[1]) if len(sys.argv) > 1 else 0.02
around = int(sys.argv[2]) if len(sys.argv) > 2 else 96
step = 2 * math.pi * R / around
corners = [(0.0, 0.0), (R, 0.0), (R, H), (R - wall, H), (R - wall, wall), (0.0, wall)]

# The profile (rho, z), from the outer pole to the inner one.
profile = []
for (r0, z0), (r1, z1) in zip(corners, corners[1:]):
    n = max(1, math.floor(math.hypot(r1 - r0, z1 - z0) / step + 0.5))
    profile += [(r0 + (r1 - r0) * k / n, z0 + (z1 - z0) * k / n) for k in range(n)]
profile.append(corners[-1])

positions, triangles = [], []
rings = len(profile) - 2
for rho, z in profile[1 : rings + 1]:
    for i in range(around):
        a = 2 * math.pi * i / around
        positions.append((rho * math.cos(a), rho * math.sin(a), z))


def at(ring, i):
    return ring * around + i % around


outer, inner = len(positions), len(positions) + 1
positions += [(0.0, 0.0, 0.0), (0.0, 0.0, wall)]
for i in range(around):
    triangles.append((outer, at(0, i + 1), at(0, i)))
    triangles.append((inner, at(rings - 1, i), at(rings - 1, i + 1)))
    for r in range(rings - 1):
        a, b, c, d = at(r, i), at(r, i + 1), at(r + 1, i + 1), at(r + 1, i)
        triangles += [(a, b, c), (a, c, d)]

print(f"# cup 1 x 1, wall {wall}: {len(positions)} vertices, {len(triangles)} triangles",
      file=sys.stderr)
for p in positions:
    print("v %.17g %.17g %.17g" % p)
for a, b, c in triangles:
    print("f %d %d %d" % (a + 1, b + 1, c + 1))
