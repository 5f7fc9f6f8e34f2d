"""OctreeMapper: integrates each registered scan into the probabilistic occupancy map."""

from __future__ import annotations

import time

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from ..config import MapperConfig, SceneConfig
from ..mapping.occupancy import OccupancyMap
from ..stage_clock import MAP, stage
from .messages import RegisteredScan, ScanReport


class OctreeMapper(LeafSystem):
    """Probabilistic occupancy over W_box (+ margin) with OctoMap's sensor model (log-odds
    hit/miss with clamping; free < 0.45 <= unknown <= 0.55 < occupied). It only maps: each new
    scan from Localisation (at its registered pose) is integrated by ray casting from the
    sensor origin, the no-return rays clearing free space up to the maximum range; returns
    inside W_box above the table are object points. A scan marked not to be integrated (its
    registration failed) is counted but leaves the map as it was.

    Input ports:
      - registered_scan (abstract RegisteredScan): the newest scan at its registered pose.
    Output ports:
      - map (abstract OccupancyMap): the current map (immutable snapshot).
      - scan_report (abstract ScanReport): statistics and timing of the last scan, with the
        registration result.
    State: abstract map and report.
    """

    def __init__(self, scene: SceneConfig, mapper: MapperConfig, dt: float):
        """`scene`: W_box and the table; `mapper`: the map's settings."""
        super().__init__()
        self.mapper = mapper
        self._scan = self.DeclareAbstractInputPort("registered_scan", AbstractValue.Make(RegisteredScan()))
        self._map = self.DeclareAbstractState(AbstractValue.Make(OccupancyMap.for_scene(scene, mapper)))
        self._rep = self.DeclareAbstractState(AbstractValue.Make(ScanReport()))
        self.DeclareStateOutputPort("map", self._map)
        self.DeclareStateOutputPort("scan_report", self._rep)
        self.DeclarePeriodicUnrestrictedUpdateEvent(dt, 0.0, self._update)

    def _update(self, context, state):
        omap: OccupancyMap = context.get_abstract_state(self._map).get_value()
        scan: RegisteredScan = self._scan.Eval(context)
        if scan.index <= omap.scan_count:
            return
        t1 = time.perf_counter()
        if scan.integrate:
            with stage(MAP, "octree"):
                new, stats = omap.integrate(scan.origin, scan.points, self.mapper.table_clearance, scan.free_rays)
        else:
            new, stats = omap.skipped(), {"points": int(len(scan.points)), "no_return_rays": int(len(scan.free_rays)),
                                          "object_points": 0, "voxels_updated": 0}
        stats["integrated"] = scan.integrate
        t_update = time.perf_counter() - t1
        state.get_mutable_abstract_state(self._map).set_value(new)
        state.get_mutable_abstract_state(self._rep).set_value(ScanReport(
            new.scan_count, **scan.info, update_s=t_update, sensor_origin=scan.origin.tolist(), **stats))
