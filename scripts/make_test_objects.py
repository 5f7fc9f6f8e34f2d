"""Writes two procedural meshes (Open3D primitives) for checking the planner on objects it
was not developed on: `mug.obj` (a cylinder with a torus handle) and `stack.obj` (a box, a
sphere and a slanted rod). Usage: python scripts/make_test_objects.py OUT_DIR, then e.g.
`nbvs reconstruct --set scene.object.kind=mesh --set scene.object.mesh=OUT_DIR/mug.obj`
(scene.object.size null: the kind's, the longest side scaled to 0.40 m)."""

import sys
from pathlib import Path

import numpy as np
import open3d as o3d


def main(out: Path) -> None:
    G = o3d.geometry.TriangleMesh
    out.mkdir(parents=True, exist_ok=True)
    cyl = G.create_cylinder(radius=0.09, height=0.22, resolution=48, split=8)
    tor = G.create_torus(torus_radius=0.06, tube_radius=0.015, radial_resolution=40, tubular_resolution=16)
    tor.rotate(tor.get_rotation_matrix_from_xyz((np.pi / 2, 0, 0)), center=(0, 0, 0))
    tor.translate((0.11, 0, 0))
    o3d.io.write_triangle_mesh(str(out / "mug.obj"), cyl + tor)
    box = G.create_box(0.2, 0.14, 0.12)
    box.translate((-0.1, -0.07, -0.2))
    sph = G.create_sphere(radius=0.07, resolution=30)
    sph.translate((0.05, 0.0, -0.01))
    rod = G.create_cylinder(radius=0.025, height=0.2, resolution=24)
    rod.rotate(rod.get_rotation_matrix_from_xyz((0, np.pi / 2.6, 0)), center=(0, 0, 0))
    rod.translate((-0.06, 0.0, 0.0))
    o3d.io.write_triangle_mesh(str(out / "stack.obj"), box + sph + rod)


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "results/test_objects"))
