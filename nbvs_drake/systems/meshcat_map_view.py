"""MeshcatMapView: the live view of `nbvs reconstruct --meshcat` draws the map and the plans."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem

from ..mapping.occupancy import OccupancyMap
from ..outputs import meshcat_draw
from ..stage_clock import OUTPUTS, stage
from .messages import PlanReport


class MeshcatMapView(LeafSystem):
    """A sink that publishes to Meshcat, checking every `period` (simulated) seconds:
    when a new scan has been integrated, the map's unknown voxels of W_box (yellow, those on
    the surface of the unknown region) and occupied voxels (blue) replace the previous ones
    at /nbvs/map; when a new plan report arrives, its candidate views, chosen view and
    planned path replace the previous ones at /nbvs/plan (drawing helpers of `meshcat_draw`);
    and the reconstructed surface (the SurfaceFusion's TSDF mesh, green) at /nbvs/model_mesh,
    redrawn after each scan.

    Input ports:
      - map (abstract OccupancyMap)
      - plan_report (abstract PlanReport): the NBVSPlanner's report
      - mesh (abstract (vertices, triangles)): the reconstructed surface
    Output ports: none (draws in Meshcat).

    What was last drawn (scan count, planned-for scan) is kept in the system, as Drake's
    MeshcatVisualizer does: a publish event cannot write the context, and the drawing is a
    side effect anyway.
    """

    def __init__(self, meshcat, kin, dummy_map: OccupancyMap, period: float):
        super().__init__()
        self.meshcat = meshcat
        self.kin = kin
        self._map = self.DeclareAbstractInputPort("map", AbstractValue.Make(dummy_map))
        self._plan = self.DeclareAbstractInputPort("plan_report", AbstractValue.Make(PlanReport()))
        self._mesh = self.DeclareAbstractInputPort("mesh", AbstractValue.Make(
            (np.zeros((0, 3)), np.zeros((0, 3), np.int32))))
        self.DeclarePeriodicPublishEvent(period, 0.0, self._publish)
        self._drawn_scan = -1
        self._drawn_plan = -1
        meshcat_draw.set_default_view(meshcat)
        meshcat_draw.set_wbox(meshcat, f"{meshcat_draw.ROOT}/wbox", dummy_map.wbox_min, dummy_map.wbox_max)

    def _publish(self, context):
        with stage(OUTPUTS, "meshcat"):
            self._draw(context)

    def _draw(self, context):
        omap: OccupancyMap = self._map.Eval(context)
        if omap.scan_count != self._drawn_scan:
            meshcat_draw.set_map_objects(self.meshcat, f"{meshcat_draw.ROOT}/map", omap)
            self._drawn_scan = omap.scan_count
            if self._mesh.HasValue(context):
                V, T = self._mesh.Eval(context)
                if len(T):
                    self.meshcat.SetTriangleMesh(f"{meshcat_draw.ROOT}/model_mesh", np.asarray(V, float).T.copy(),
                                                 np.asarray(T, np.int32).T.copy(),
                                                 meshcat_draw.rgba(meshcat_draw.MODEL_MESH_RGBA))
        report: PlanReport = self._plan.Eval(context)
        k = report.scan
        if k != self._drawn_plan:
            self.meshcat.Delete(f"{meshcat_draw.ROOT}/plan")
            if report.status == "ok":
                meshcat_draw.set_plan_objects(self.meshcat, f"{meshcat_draw.ROOT}/plan", report.to_json(), self.kin)
            self._drawn_plan = k
        return EventStatus.Succeeded()


def add_meshcat_views(builder, meshcat, scene_graph, mapper, planner, kin, dummy_map: OccupancyMap,
                      period: float, fusion=None):
    """Adds to a mission diagram a MeshcatVisualizer of the scene (illustration geometry:
    robot, table, object; published every `period`) and a MeshcatMapView fed by the mapper's
    map, the planner's report and the SurfaceFusion's mesh (`fusion`). Returns (visualizer,
    map_view)."""
    from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams, Role
    vis = MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, MeshcatVisualizerParams(
        role=Role.kIllustration, prefix="robot", publish_period=period))
    view = builder.AddNamedSystem("meshcat_map_view", MeshcatMapView(meshcat, kin, dummy_map, period))
    builder.Connect(mapper.GetOutputPort("map"), view.GetInputPort("map"))
    builder.Connect(planner.GetOutputPort("report"), view.GetInputPort("plan_report"))
    if fusion is not None:
        builder.Connect(fusion.GetOutputPort("mesh"), view.GetInputPort("mesh"))
    return vis, view
