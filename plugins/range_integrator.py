"""Range integrator: what a LiDAR beam returns, with no BSDF or emitter work.

For every beam of a ``tractor_lidar`` (or any sensor exposing ``n_positions``,
``n_angles`` and ``footprint``) it casts the sub-beam rays with
``ray_intersect_preliminary`` (no surface interaction is built) and returns

- ``range``: distance to the first return in metres; ``escape`` for beams that meet
  nothing (above the horizon, or with the ground disabled);
- ``class``: 0 escape, 1 ground, 2 wood, 3 leaf;
- ``element_id``: branch index for wood, leaf index for leaves, 0xFFFFFFFF otherwise
  (for instanced trees, the index within the tree's prototype);
- ``tree_id`` (scenes of several plants): the tree or plant that was hit;
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
 * - hit_rule
   - |string|
   - How a footprint's sub-beams make one return: ``"fraction"`` (default) or ``"any"``.

The footprint is reduced here, never through the film.  ``"fraction"``: first-return
range is the minimum over sub-beams, class and id are those of the sub-beam that gave
it.  ``"any"`` (SIMLIDAR §3.1: a beam hits a branch when any point of its dot matrix
lies inside it): a beam with any sub-beam on vegetation returns the nearest vegetation
sub-beam's range, class and id, even when another sub-beam met the ground nearer;
other beams as under ``"fraction"``.  The hit fraction is a block sum under both rules.
With footprint P = 0 none of that code runs and both rules agree.

Which shape is wood or leaf, and which branch a triangle or curve segment belongs to,
is given by the scene builder through :meth:`set_tables`.

A real scanner (``[sensor]``, :mod:`simlidar_mi.lidar.sensor`) calls :meth:`trace_subrays`
instead: every divergent sub-ray of a range of beams, unreduced (range, class, ids and, when
energies are needed, |cos incidence| and reflectance), for the waveform built on the host.
:meth:`trace` is untouched by it, so scans without a sensor keep their bytes and speed.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from simlidar_mi.lidar.packets import aligned_span
from simlidar_mi.plugins.waveform_reader import MAX_SUBRAYS, read_pulses

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
        self.hit_rule = str(props.get("hit_rule", "fraction"))
        if self.hit_rule not in ("fraction", "any"):
            raise ValueError(f"lidar_range: hit_rule must be 'fraction' or 'any', got {self.hit_rule!r}")
        self._class = mi.UInt32(np.zeros(1, np.uint32))
        self._base = mi.UInt32(np.zeros(1, np.uint32))
        self._prim = mi.UInt32(np.full(1, NO_ID, np.uint32))
        self._instanced = False
        self._prim_tree = None
        self._prim_n = None  # set_normals: incidence from a table
        self._class_rho = mi.Float(np.array([0.0, 0.20, 0.35, 0.45], np.float32))
        self._shape_rho = None
        self._terrain = None  # set_terrain: the ground mesh's cracks are closed by a second cast

    def set_tables(self, shape_class: np.ndarray, shape_base: np.ndarray,
                   prim_element: np.ndarray, instance_tree: np.ndarray | None = None,
                   instance_proto: np.ndarray | None = None, group_class: np.ndarray | None = None,
                   group_base: np.ndarray | None = None, prim_tree: np.ndarray | None = None) -> None:
        """Per-shape class and offset (indexed by Dr.Jit registry id), and the element
        id of every primitive (triangle, cylinder, curve segment) at shape_base + prim_index.

        Scenes with instances also give, per instance registry id, its tree id and its
        prototype's first row in ``group_class``/``group_base`` (rows: prototype ×
        shape index within the shape group).  Scenes of several plants without instances
        give ``prim_tree``, the tree id of every primitive, laid out like ``prim_element``
        (also when their big meshes sit in one identity instance, see scene.build)."""
        u32 = lambda a: mi.UInt32(np.ascontiguousarray(a, np.uint32))  # noqa: E731
        self._class, self._base, self._prim = u32(shape_class), u32(shape_base), u32(prim_element)
        self._instanced = instance_proto is not None
        self._inst_has_tree = instance_tree is not None  # False: only the flat meshes' identity instance
        # prim_tree (several plants, no placed trees) wins over instance_tree: the flat
        # meshes' identity instance holds every tree of an orchard.
        self._prim_tree = u32(prim_tree) if prim_tree is not None else None
        if self._instanced:
            self._inst_proto = u32(instance_proto)
            if self._inst_has_tree:
                self._inst_tree = u32(instance_tree)
            self._group_class, self._group_base = u32(group_class), u32(group_base)

    def set_terrain(self, mesh, shape_id: int, cell_m: float) -> None:
        """The terrain mesh (top level, registry id ``shape_id``, grid cells ``cell_m`` apart).

        Embree's ray–triangle test is not watertight: a ray through the exact edge two
        triangles share can miss both, and a scan's regular rows meet a regular grid's edges
        exactly (rows 0.2 m apart over 1 m cells lost 0.8 % of their pulses, BENCHMARKS §18).
        Rays that meet nothing are cast again from an origin nudged sideways (a ten-thousandth
        of a cell, or a few float32 steps of the origin; up to three directions); a terrain hit
        of that cast gives the triangle, and the range is the *original* ray's distance to that
        triangle's plane, which holds the edge.  Only escaped rays pay for it."""
        self._terrain = (mesh.vertex_positions_buffer(), mesh.faces_buffer(), int(shape_id),
                         float(cell_m) * 1e-4)

    def _terrain_retry(self, scene: mi.Scene, ray: mi.Ray3f, hit):
        """(found, t, unit normal, prim index) of the escaped rays that the terrain's cracks let
        through (see :meth:`set_terrain`)."""
        verts, faces, sid_t, nudge_cell = self._terrain
        o, d = ray.o, ray.d
        # Sideways ⟂ d, along no grid axis or cell diagonal (a fixed non-axis vector crossed
        # with d), then the opposite way, then the other perpendicular: a nudged ray may meet a
        # leaf or twig the beam passed within the nudge of (at 100 ha, 141 of 20 M beams with one
        # direction), and only a terrain hit gives the beam's range.
        side = dr.normalize(dr.cross(d, mi.Vector3f(1.0, 0.6180339887, 0.3819660113)))
        big = dr.maximum(dr.maximum(dr.abs(o.x), dr.abs(o.y)), dr.abs(o.z))
        nudge = dr.maximum(nudge_cell, big * 6e-7)  # ≥ 5 float32 steps of the origin
        found, prim = mi.Bool(False), mi.UInt32(0)
        n = mi.Vector3f(0.0, 0.0, 1.0)
        t = mi.Float(dr.inf)
        for step in (side, -side, dr.cross(d, side)):
            retry = ~hit & ~found
            pi2 = scene.ray_intersect_preliminary(mi.Ray3f(o + nudge * step, d, ray.time), coherent=True,
                                                  active=retry)
            on = retry & pi2.is_valid() & (dr.reinterpret_array(mi.UInt32, pi2.shape) == sid_t)
            f = dr.gather(mi.Vector3u, faces, pi2.prim_index, on)
            p0, p1, p2 = (dr.gather(mi.Vector3f, verts, f[k], on) for k in range(3))
            n_k = dr.normalize(dr.cross(p1 - p0, p2 - p0))
            t_k = dr.dot(p0 - o, n_k) / dr.dot(d, n_k)  # the original ray against the triangle's plane
            ok = on & dr.isfinite(t_k) & (t_k > 0.0)
            t, n, prim = dr.select(ok, t_k, t), dr.select(ok, n_k, n), dr.select(ok, pi2.prim_index, prim)
            found |= ok
        return found, t, n, prim

    def trace(self, scene: mi.Scene, sensor: mi.Sensor, beam_start: int = 0,
              beam_count: int | None = None) -> dict:
        """Cast beams [beam_start, beam_start + beam_count) (default: every beam); return
        Dr.Jit arrays of length beam_count (row-major beam order: position, angle).

        Every value is a function of its global beam index alone, so a scan traced in
        chunks has the bytes of the whole-scan call (which runs the code it always did)."""
        N, M, P = sensor.n_positions, sensor.n_angles, sensor.footprint
        S = (P + 1) ** 2
        count = N * M - beam_start if beam_count is None else int(beam_count)
        # Widened to packet boundaries of the whole scan (simlidar_mi.lidar.packets), so each
        # ray shares its Embree packet with the rays it shares it with in a whole-scan trace.
        start, n, skip = aligned_span(beam_start, count, N * M, sensor.first_beam)
        idx = dr.arange(mi.UInt32, n * S)
        beam = idx // S if S > 1 else idx          # chunk-local: indexes the block reductions
        # opaque: one kernel for every chunk (a literal start compiled a new kernel per chunk)
        glob = beam if start == 0 else dr.opaque(mi.UInt32, start) + beam
        ray = _beam_ray(sensor, glob, idx % S if S > 1 else None)
        pi = scene.ray_intersect_preliminary(ray, coherent=True)
        hit = pi.is_valid()
        cls, elem, tree, _, _, _ = self._classify(pi, hit)
        t = dr.select(hit, pi.t, dr.inf)
        if self._terrain is not None:
            found, t2, _, _ = self._terrain_retry(scene, ray, hit)
            t, cls, elem, tree = self._on_terrain(found, t2, t, cls, elem, tree)
        t, cls, elem, tree, _ = self._ground(ray, t, cls, elem, tree)
        veg = (cls == WOOD) | (cls == LEAF)
        if S > 1:
            t_min = dr.block_reduce(dr.ReduceOp.Min, t, S)
            if self.hit_rule == "any":
                # The nearest vegetation sub-beam wins over nearer ground (an infinite t_veg: none).
                t_veg = dr.block_reduce(dr.ReduceOp.Min, dr.select(veg, t, dr.inf), S)
                any_veg = dr.isfinite(t_veg)
                t_min = dr.select(any_veg, t_veg, t_min)
                first = (t == dr.gather(mi.Float, t_min, beam)) & (veg | ~dr.gather(mi.Bool, any_veg, beam))
            else:
                first = t == dr.gather(mi.Float, t_min, beam)
            cls_first = dr.block_reduce(dr.ReduceOp.Min, dr.select(first, cls, 255), S)
            elem = dr.block_reduce(dr.ReduceOp.Min, dr.select(first, elem, NO_ID), S)
            if tree is not None:
                tree = dr.block_reduce(dr.ReduceOp.Min, dr.select(first, tree, NO_ID), S)
            hit_fraction = dr.block_reduce(dr.ReduceOp.Add, dr.select(veg, 1.0, 0.0), S) / S
            t, cls = t_min, dr.select(dr.isinf(t_min), ESCAPE, cls_first)
        else:
            hit_fraction = dr.select(veg, 1.0, 0.0)
        rng = dr.select(dr.isinf(t), self.escape, t)
        # class as uint8 from the kernel: a quarter of the bytes, and no host-side conversion
        out = {"range": rng, "class": dr.uint8_array_t(mi.UInt32)(cls), "element_id": elem,
               "hit_fraction": hit_fraction}
        if tree is not None:
            out["tree_id"] = tree
        dr.eval(out)  # one kernel: reading the arrays one by one would trace twice
        return _kept(out, skip, count, 1, n)

    def set_reflectance(self, class_reflectance: np.ndarray, shape_reflectance: np.ndarray | None = None) -> None:
        """ρ per class code (escape, ground, wood, leaf) and, per shape registry id, a shape's own
        reflectance (negative: use its class's).  Instanced shapes use their class's."""
        self._class_rho = mi.Float(np.ascontiguousarray(class_reflectance, np.float32))
        own = shape_reflectance is not None and bool(np.any(np.asarray(shape_reflectance) >= 0))
        self._shape_rho = mi.Float(np.ascontiguousarray(shape_reflectance, np.float32)) if own else None

    def set_normals(self, prim_normal: np.ndarray, instance_yaw_rad: np.ndarray | None = None) -> None:
        """Unit normal of every primitive (n, 3), laid out like ``prim_element`` and in its
        shape's own frame, and per instance registry id the yaw that turns a prototype's
        normals into the scene frame.  With them, :meth:`trace_subrays` reads incidence from
        a table instead of Mitsuba's surface interaction (see BuiltScene.prim_normals)."""
        n = np.ascontiguousarray(prim_normal, np.float32).reshape(-1, 3)
        self._prim_n = [mi.Float(np.ascontiguousarray(n[:, j])) for j in range(3)]
        yaw = None if instance_yaw_rad is None else np.asarray(instance_yaw_rad, np.float64)
        self._inst_cs = None
        if yaw is not None and np.any(yaw != 0):
            self._inst_cs = (mi.Float(np.cos(yaw).astype(np.float32)), mi.Float(np.sin(yaw).astype(np.float32)))

    def trace_subrays(self, scene: mi.Scene, sensor: mi.Sensor, offsets_rad: np.ndarray,
                      beam_start: int, beam_count: int, normals: bool = False) -> dict:
        """Cast every divergent sub-ray of beams [beam_start, beam_start + beam_count).

        Each dot-matrix sub-beam q < (P+1)² carries the S sub-rays of ``offsets_rad`` (S, 2):
        angular offsets along (u, v) ⟂ the sub-beam's direction.  Returns Dr.Jit arrays of
        length beam_count·(P+1)²·S, laid out (beam, q, j): ``t`` (inf where the sub-ray escaped),
        ``class``, ``element_id``, ``tree_id`` (scenes of several plants), and with ``normals``
        ``cos_incidence`` (|cos| between the sub-ray and the geometric normal; 0 on escapes) and
        ``reflectance`` (see :meth:`set_reflectance`).  No reduction: the waveform is built on
        the host.
        """
        ray, Q, S, skip, n_traced = _subray_rays(sensor, offsets_rad, beam_start, beam_count)
        pi = scene.ray_intersect_preliminary(ray, coherent=True)
        hit = pi.is_valid()
        cls, elem, tree, sid, in_inst, row = self._classify(pi, hit)
        t = dr.select(hit, pi.t, dr.inf)
        found = None
        if self._terrain is not None:
            found, t2, n2, prim2 = self._terrain_retry(scene, ray, hit)
            t, cls, elem, tree = self._on_terrain(found, t2, t, cls, elem, tree)
            sid = dr.select(found, self._terrain[2], sid)
            row = dr.select(found, dr.gather(mi.UInt32, self._base, sid) + prim2, row)
            hit = hit | found
        out = {}
        if normals:
            if self._prim_n is not None:
                nx, ny, nz = (dr.gather(mi.Float, a, row, hit) for a in self._prim_n)
                if self._inst_cs is not None:  # placed trees: turn the prototype's normal by the yaw
                    iid = dr.reinterpret_array(mi.UInt32, pi.instance)
                    c = dr.gather(mi.Float, self._inst_cs[0], iid, in_inst)
                    s_ = dr.gather(mi.Float, self._inst_cs[1], iid, in_inst)
                    nx, ny = dr.select(in_inst, c * nx - s_ * ny, nx), dr.select(in_inst, s_ * nx + c * ny, ny)
                n = mi.Vector3f(nx, ny, nz)
            else:  # analytic shapes: Mitsuba's geometric normal
                n = pi.compute_surface_interaction(ray, mi.RayFlags.Minimal, pi.is_valid()).n
                if found is not None:
                    n = dr.select(found, n2, n)
            cos_i = dr.select(hit, dr.abs(dr.dot(n, ray.d)), 0.0)
            rho = dr.gather(mi.Float, self._class_rho, cls, hit)
            if self._shape_rho is not None:
                own = dr.gather(mi.Float, self._shape_rho, sid, hit & ~in_inst)
                rho = dr.select(hit & ~in_inst & (own >= 0.0), own, rho)
        t, cls, elem, tree, use_ground = self._ground(ray, t, cls, elem, tree)
        if self.ground:
            if normals:  # the ground's normal is +z
                cos_i = dr.select(use_ground, dr.abs(ray.d.z), cos_i)
                rho = dr.select(use_ground, dr.gather(mi.Float, self._class_rho, mi.UInt32(GROUND)), rho)
        # class as uint8 from the kernel, as trace() gives it: a quarter of the bytes
        out.update({"t": t, "class": dr.uint8_array_t(mi.UInt32)(cls), "element_id": elem})
        if tree is not None:
            out["tree_id"] = tree
        if normals:
            out["cos_incidence"], out["reflectance"] = cos_i, rho
        dr.eval(out)  # one kernel for every output
        return _kept(out, skip, int(beam_count), Q * S, n_traced)

    #: Sub-rays a beam :meth:`read_waveforms` takes (wider beams: the host reads them).
    read_max_subrays = MAX_SUBRAYS

    def read_waveforms(self, traced: dict, n_sub: int, weight: np.ndarray, model) -> dict:
        """Per beam of :meth:`trace_subrays`' arrays ``traced``: the echo of a beam whose
        sub-rays meet one surface, read in one kernel (``waveform_reader.read_pulses``; the
        ``model``'s pulse, threshold, range limits and echo rule), or state 2 for the host."""
        return read_pulses(traced, n_sub, weight, r_ref_m=model.r_ref_m, pulse_length_ns=model.pulse_length_ns,
                           detection_threshold=model.detection_threshold, range_min_m=model.range_min_m,
                           range_max_m=model.range_max_m, echo_rule=model.echo_rule)

    def cast_subrays(self, scene: mi.Scene, sensor: mi.Sensor, offsets_rad: np.ndarray,
                     beam_start: int, beam_count: int):
        """The bare cast of :meth:`trace_subrays`' rays: ``pi.t`` and ``pi.is_valid()`` of
        ``ray_intersect_preliminary``, evaluated, nothing else (the floor a benchmark
        compares a scan with)."""
        ray = _subray_rays(sensor, offsets_rad, beam_start, beam_count)[0]
        pi = scene.ray_intersect_preliminary(ray, coherent=True)
        t, valid = pi.t, pi.is_valid()
        dr.eval(t, valid)
        return t, valid

    def _on_terrain(self, found, t2, t, cls, elem, tree):
        """The terrain hits of :meth:`_terrain_retry` in place of escapes: class and element
        of the terrain mesh, no tree."""
        cls = dr.select(found, dr.gather(mi.UInt32, self._class, mi.UInt32(self._terrain[2])), cls)
        elem = dr.select(found, NO_ID, elem)
        if tree is not None:
            tree = dr.select(found, NO_ID, tree)
        return dr.select(found, t2, t), cls, elem, tree

    def _ground(self, ray, t, cls, elem, tree):
        """The analytic ground plane after vegetation: a beam that passes every shape meets
        it.  Returns (t, cls, elem, tree, use_ground); use_ground is None without a ground."""
        if not self.ground:
            return t, cls, elem, tree, None
        down = ray.d.z < 0.0
        t_ground = dr.select(down, (self.ground_z - ray.o.z) / ray.d.z, dr.inf)
        use_ground = down & (t_ground < t)
        t = dr.select(use_ground, t_ground, t)
        cls = dr.select(use_ground, GROUND, cls)
        elem = dr.select(use_ground, NO_ID, elem)
        if tree is not None:
            tree = dr.select(use_ground, NO_ID, tree)
        return t, cls, elem, tree, use_ground

    def _classify(self, pi, hit):
        """Class, element id, tree id (or None), shape registry id and in-instance mask of
        preliminary intersections (the lookups of :meth:`trace`)."""
        sid = dr.reinterpret_array(mi.UInt32, pi.shape)
        cls = dr.gather(mi.UInt32, self._class, sid, hit)
        base = dr.gather(mi.UInt32, self._base, sid, hit)
        tree, in_inst = None, mi.Bool(False)
        if self._instanced:
            iid = dr.reinterpret_array(mi.UInt32, pi.instance)
            in_inst = hit & (iid != 0)
            row = dr.gather(mi.UInt32, self._inst_proto, iid, in_inst) + pi.shape_index
            cls = dr.select(in_inst, dr.gather(mi.UInt32, self._group_class, row, in_inst), cls)
            base = dr.select(in_inst, dr.gather(mi.UInt32, self._group_base, row, in_inst), base)
            if self._inst_has_tree:
                tree = dr.select(in_inst, dr.gather(mi.UInt32, self._inst_tree, iid, in_inst), NO_ID)
        cls = dr.select(hit, cls, ESCAPE)
        row = base + pi.prim_index
        elem = dr.select(hit, dr.gather(mi.UInt32, self._prim, row, hit), NO_ID)
        if self._prim_tree is not None:
            tree = dr.select(hit, dr.gather(mi.UInt32, self._prim_tree, row, hit), NO_ID)
        return cls, elem, tree, sid, in_inst, row

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
        return (f"RangeIntegrator[escape={self.escape}, ground={self.ground}, ground_z={self.ground_z}, "
                f"hit_rule={self.hit_rule}]")


def _kept(out: dict, skip: int, count: int, per_beam: int, traced: int) -> dict:
    """The arrays of beams [skip, skip + count) of a trace of ``traced`` beams (``per_beam``
    entries a beam): the requested beams of a packet-aligned trace."""
    if skip == 0 and count == traced:
        return out
    keep = dr.arange(mi.UInt32, skip * per_beam, (skip + count) * per_beam)
    out = {k: dr.gather(type(v), v, keep) for k, v in out.items()}
    dr.eval(out)
    return out



def _subray_rays(sensor: mi.Sensor, offsets_rad: np.ndarray, beam_start: int, beam_count: int):
    """The sub-rays of :meth:`RangeIntegrator.trace_subrays` (beams widened to packet
    boundaries) and (Q, S, skip, traced beams)."""
    Q = (sensor.footprint + 1) ** 2
    off = np.asarray(offsets_rad, np.float64).reshape(-1, 2)
    S = len(off)
    start, n_traced, skip = aligned_span(int(beam_start), int(beam_count), sensor.n_positions * sensor.n_angles,
                                         sensor.first_beam)  # packet boundaries, as in trace()
    idx = dr.arange(mi.UInt32, n_traced * Q * S)
    rest = idx // S if S > 1 else idx
    # opaque: one kernel for every chunk (a literal start compiled a new kernel per chunk,
    # ~70 ms and a few MB each)
    beam = dr.opaque(mi.UInt32, start) + (rest // Q if Q > 1 else rest)
    ray = _beam_ray(sensor, beam, rest % Q if Q > 1 else None)
    if S > 1 or np.any(off != 0):
        j = idx % S
        tan_u = dr.gather(mi.Float, mi.Float(np.tan(off[:, 0]).astype(np.float32)), j)
        tan_v = dr.gather(mi.Float, mi.Float(np.tan(off[:, 1]).astype(np.float32)), j)
        d = ray.d
        # (u, v) ⟂ d: u horizontal unless d is near vertical; the spiral is round, so only
        # its orientation depends on this choice.
        helper = dr.select(dr.abs(d.z) < 0.9, mi.Vector3f(0, 0, 1), mi.Vector3f(1, 0, 0))
        u = dr.normalize(dr.cross(helper, d))
        v = dr.cross(d, u)
        ray = mi.Ray3f(ray.o, dr.normalize(d + tan_u * u + tan_v * v), ray.time)
    return ray, Q, S, skip, n_traced


def _beam_ray(sensor: mi.Sensor, beam, sub=None):
    """The ray of global beam index ``beam`` (row-major: position, angle) through dot-matrix
    sub-beam ``sub`` of the sensor's footprint (None: the beam's centre); ``trace`` and
    ``trace_subrays`` both aim their rays here.  Our sensors make it from the integers
    (``beam_ray``); any other sensor is asked through ``sample_ray`` at the beam's centre."""
    if hasattr(sensor, "beam_ray"):
        return sensor.beam_ray(beam, sub)
    M, N, P = sensor.n_angles, sensor.n_positions, sensor.footprint
    i, k = beam // M, beam % M
    pos = mi.Vector2f((mi.Float(k) + 0.5) / M, (mi.Float(i) + 0.5) / N)
    if sub is None:
        aperture = mi.Vector2f(0.5, 0.5)
    else:
        aperture = mi.Vector2f(mi.Float(sub % (P + 1)) / P, mi.Float(sub // (P + 1)) / P)
    ray, _ = sensor.sample_ray(0.0, 0.0, pos, aperture)
    return ray


def register() -> None:
    mi.register_integrator(PLUGIN_NAME, lambda props: RangeIntegrator(props))
