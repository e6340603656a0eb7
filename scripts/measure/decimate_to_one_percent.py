# How many triangles a surface's boundary needs to lie within 1 % of the bounding box's
# diagonal of a closed surface, both ways, by MeshLab's quadric edge collapse (optimal
# placement, topology kept): the fewest of a ladder of counts that get there. Distances are
# sampled as `soft-tissue mesh tetrahedralize` reports them (vertices, edge midpoints and
# centroids), by trimesh's closest-point query.
#
#   pip install trimesh pymeshlab rtree   (it imports surface_distance.py, beside it)
#   python3 decimate_to_one_percent.py SURFACE
#
# Prints the input's triangle count, then COUNT:IN->OUT/OUT->IN (% of the diagonal) per
# count tried, stopping below 0.95 % both ways.
import sys

import pymeshlab

from surface_distance import Reference

ref = Reference(sys.argv[1])
surf = ref.surf
two_way = ref.two_way


out = []
for n in [800, 1000, 1200, 1400, 1600, 1800, 2000, 2200, 2500, 2800, 3200, 3600, 4000, 5000, 6000, 8000]:
    if n >= len(surf.faces):
        break
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(surf.vertices, surf.faces))
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=n, qualitythr=0.3, preservenormal=True, preservetopology=True,
        optimalplacement=True, planarquadric=True, autoclean=True)
    m = ms.current_mesh()
    a, b = two_way(m.vertex_matrix(), m.face_matrix())
    out.append('%d:%.2f/%.2f' % (len(m.face_matrix()), a, b))
    if max(a, b) < 0.95:
        break
print(sys.argv[1].split('/')[-1], len(surf.faces), ' '.join(out), flush=True)
