"""Range integrator: what a LiDAR beam returns, with no BSDF or emitter work.

For every beam of a ``tractor_lidar`` (or any sensor exposing ``n_positions``,
``n_angles`` and ``footprint``) it casts the sub-beam rays with
``ray_intersect_preliminary`` (no surface interaction is built) and returns

- ``range``: distance to the first return in metres; ``escape`` for beams that meet
  nothing (above the horizon, or with the ground disabled);
- ``class``: 0 escape, 1 ground, 2 wood, 3 leaf;
- ``element_id``: branch index for wood, leaf index for leaves, 0xFFFFFFFF otherwise;
- ``hit_fraction``: share of sub-beams whose first return is vegetation (wood or leaf).

.. pluginparameters::

 * - escape
   - |float|
   - Range reported for beams that hit nothing (SIMLIDAR's escape distance). Default 1000 m.
 * - ground
   - |bool|
   - An infinite analytic ground plane z = ground_z (exact in float32; no mesh). Default true.
 * - ground_z
   - |float|
   - Height of the ground in the scene frame. Default 0.

The footprint is reduced here, never through the film: first-return range is the
minimum over sub-beams, class and id are those of the sub-beam that gave it, and the
hit fraction a block sum.  With footprint P = 0 none of that code runs.

Which shape is wood or leaf, and which branch a triangle or curve segment belongs to,
is given by the scene builder through :meth:`set_tables`.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

PLUGIN_NAME = "lidar_range"
ESCAPE, GROUND, WOOD, LEAF = 0, 1, 2, 3
NO_ID = 0xFFFFFFFF


class RangeIntegrator(mi.SamplingIntegrator):
    """First-return range, class and element id per beam (see module docstring)."""

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.escape = float(props.get("escape", 1000.0))
        self.ground = bool(props.get("ground", True))
        self.ground_z = float(props.get("ground_z", 0.0))
        self._class = mi.UInt32(np.zeros(1, np.uint32))
        self._base = mi.UInt32(np.zeros(1, np.uint32))
        self._prim = mi.UInt32(np.full(1, NO_ID, np.uint32))

    def set_tables(self, shape_class: np.ndarray, shape_base: np.ndarray,
                   prim_element: np.ndarray) -> None:
        """Per-shape class and offset (indexed by Dr.Jit registry id), and the element
        id of every primitive (triangle, cylinder, curve segment) at shape_base + prim_index."""
        self._class = mi.UInt32(np.ascontiguousarray(shape_class, np.uint32))
        self._base = mi.UInt32(np.ascontiguousarray(shape_base, np.uint32))
        self._prim = mi.UInt32(np.ascontiguousarray(prim_element, np.uint32))

    def trace(self, scene: mi.Scene, sensor: mi.Sensor) -> dict:
        """Cast every beam; return Dr.Jit arrays of length N·M (row-major: position, angle)."""
        N, M, P = sensor.n_positions, sensor.n_angles, sensor.footprint
        S = (P + 1) ** 2
        idx = dr.arange(mi.UInt32, N * M * S)
        beam = idx // S if S > 1 else idx
        i, k = beam // M, beam % M
        pos = mi.Vector2f((mi.Float(k) + 0.5) / M, (mi.Float(i) + 0.5) / N)
        if S > 1:
            sub = idx % S
            aperture = mi.Vector2f(mi.Float(sub % (P + 1)) / P, mi.Float(sub // (P + 1)) / P)
        else:
            aperture = mi.Vector2f(0.5, 0.5)
        ray, _ = sensor.sample_ray(0.0, 0.0, pos, aperture)
        pi = scene.ray_intersect_preliminary(ray, coherent=True)
        hit = pi.is_valid()
        sid = dr.reinterpret_array(mi.UInt32, pi.shape)
        cls = dr.select(hit, dr.gather(mi.UInt32, self._class, sid, hit), ESCAPE)
        elem = dr.select(hit, dr.gather(mi.UInt32, self._prim,
                                        dr.gather(mi.UInt32, self._base, sid, hit) + pi.prim_index,
                                        hit), NO_ID)
        t = dr.select(hit, pi.t, dr.inf)
        if self.ground:
            # Ground after vegetation: a beam that passes every shape meets the plane.
            down = ray.d.z < 0.0
            t_ground = dr.select(down, (self.ground_z - ray.o.z) / ray.d.z, dr.inf)
            use_ground = down & (t_ground < t)
            t = dr.select(use_ground, t_ground, t)
            cls = dr.select(use_ground, GROUND, cls)
            elem = dr.select(use_ground, NO_ID, elem)
        veg = (cls == WOOD) | (cls == LEAF)
        if S > 1:
            t_min = dr.block_reduce(dr.ReduceOp.Min, t, S)
            first = t == dr.gather(mi.Float, t_min, beam)
            cls_first = dr.block_reduce(dr.ReduceOp.Min, dr.select(first, cls, 255), S)
            elem = dr.block_reduce(dr.ReduceOp.Min, dr.select(first, elem, NO_ID), S)
            hit_fraction = dr.block_reduce(dr.ReduceOp.Add, dr.select(veg, 1.0, 0.0), S) / S
            t, cls = t_min, dr.select(dr.isinf(t_min), ESCAPE, cls_first)
        else:
            hit_fraction = dr.select(veg, 1.0, 0.0)
        rng = dr.select(dr.isinf(t), self.escape, t)
        out = {"range": rng, "class": cls, "element_id": elem, "hit_fraction": hit_fraction}
        dr.eval(out)  # one kernel: reading the arrays one by one would trace twice
        return out

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        """For ``mi.render``: a (N, M, 4) tensor of range, class, element id, hit fraction.

        Element ids pass through float32 here and are exact only below 2**24; the
        Python API (:meth:`trace`) keeps them as uint32."""
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        out = self.trace(scene, sensor)
        N, M = sensor.n_positions, sensor.n_angles
        elem = dr.select(out["element_id"] == NO_ID, -1.0, mi.Float(out["element_id"]))
        data = dr.ravel(mi.Vector4f(out["range"], mi.Float(out["class"]), elem, out["hit_fraction"]))
        return mi.TensorXf(data, shape=(N, M, 4))

    def aov_names(self):
        return ["range", "class", "element_id", "hit_fraction"]

    def to_string(self) -> str:
        return f"RangeIntegrator[escape={self.escape}, ground={self.ground}, ground_z={self.ground_z}]"


def register() -> None:
    mi.register_integrator(PLUGIN_NAME, lambda props: RangeIntegrator(props))
