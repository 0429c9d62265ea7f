"""Scan products ↔ OpenEXR files (the OpenEXR 3.x Python package).

Channels (all N × M, row = position y_i, column = angle θ_k):
``range`` float32 metres, ``class`` uint32 (0 escape, 1 ground, 2 wood, 3 leaf),
``branch_id`` uint32 (element id, 0xFFFFFFFF for none), ``theta_deg`` float32,
``y_m`` float32 (y − origin_y, exact in float32 near the origin), and
``hit_fraction`` float32 when a footprint was simulated, and ``class_half``: the class
again as half floats (0.0 … 3.0).  Image tools (OpenImageIO and so ``oiiotool``, GIMP,
a TIFF conversion) scale unsigned-integer channels to 0 … 1, so they show ``class`` as
0 … 7e-10; ``class_half`` is what they display.  Header attributes hold
every scan setting, the footprint's ``hit_rule``, the seed, the scene file's SHA-256
and the float64 origin.

A scan with a ``[sensor]`` (``result.echoes`` set) keeps those channels for echo 1 and
adds ``n_returns`` (uint32), ``intensity`` (float32 echo energy E, when the sensor's
intensity is on) and, for each return r = 2 … max_returns, the layer ``echo{r}.range``
(float32, escape distance where the beam has fewer echoes), ``echo{r}.class``,
``echo{r}.branch_id`` (uint32, 0 / 0xFFFFFFFF where absent), ``echo{r}.intensity``
(with intensity on), ``echo{r}.tree_id`` (scenes of several plants) and
``echo{r}.class_half``, and ``n_returns_half`` (0.0 … 15.0) for the same image tools.  The header
attribute ``simlidar_sensor`` holds the resolved sensor as JSON.  The LAS intensity counts per
unit E are chosen per scan from all its echoes (points.las, VLR record 2), so they are not in
this header, which a streamed scan writes before its first row.  Without echoes nothing
changes, byte for byte.

Id channels (``branch_id``, ``tree_id``, ``echo{r}.…``) have no half copy: half floats hold
integers up to 2048 only, float32 up to 2^24, and 0xFFFFFFFF neither.  OpenImageIO reads them
exactly when asked for uint: ``OpenImageIO.ImageInput.open(path).read_image(0, 0, c, c + 1,
"uint")`` (c the channel's index in ``spec().channelnames``) gives the uint32 ids; its default
float read gives id / (2^32 − 1) rounded to float32, which loses ids above 2^24
(tests/test_trust3_las.py).
"""
from __future__ import annotations

import json
import threading
import zlib
from pathlib import Path
import numpy as np
import OpenEXR

from ..errors import SimlidarError
from .atomic import atomic_file
from .scan_record import ScanRecord


def header_value(value):
    """A Python value as an OpenEXR header attribute that keeps its precision.

    A plain float would be stored as float32, so floats and short vectors become
    float64 arrays (OpenEXR has float64 vectors of 1 to 3 elements only); longer
    vectors are stored as JSON text.
    """
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, (int, np.integer)):
        return int(value) if abs(int(value)) < 2**31 else str(int(value))
    if isinstance(value, (float, np.floating)):
        return np.array([float(value)], np.float64)
    if isinstance(value, (np.ndarray, list, tuple)):
        flat = [float(x) for x in np.asarray(value, np.float64).ravel()]
        return np.asarray(flat, np.float64) if 1 <= len(flat) <= 3 else json.dumps(flat)
    return str(value)


#: Suffix of the half-float copy of each class channel (module docstring); the writer fills
#: ``X_half`` from the rows' ``X``.
HALF = "_half"


#: Channels given a half copy (module docstring): small counts that image tools would scale to 0 … 1.
HALF_COPIED = ("class", "n_returns")


def with_half_copies(dtypes: dict) -> dict:
    """``dtypes`` plus a float16 ``X_half`` for each class channel ``X`` (``class``, ``echo{r}.class``)
    and for ``n_returns``."""
    return {**dtypes, **{f"{k}{HALF}": np.float16 for k in dtypes if k in HALF_COPIED or k.endswith(".class")}}


#: Header attributes holding the broadcast constants (float64 JSON lists, exact) that
#: were N × M float32 channels before issue #8: tractor θ per column and y per row (real
#: y, not y − origin), other platforms' column angle and row coordinate.
CONSTANT_ATTRS = {"theta_deg": "simlidar_theta_deg", "y_m": "simlidar_y_m",
                  "angle_deg": "simlidar_angle_deg", "row_coord": "simlidar_row_coord"}


def scan_exr_layout(result, *, seed: int | None = None, scene_sha256: str = "",
                    extra: dict | None = None) -> tuple[dict, dict]:
    """(header, channel dtypes) of a scan's EXR (module docstring); ``result`` needs only
    ``settings``, ``pattern``, ``origin_m`` and, for the channel set, ``tree_id``."""
    s, p = result.settings, result.pattern
    dtypes = {"range": np.float32, "class": np.uint32, "branch_id": np.uint32}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "origin_m": np.asarray(result.origin_m, np.float64), "scene_sha256": scene_sha256,
              "hit_rule": p.hit_rule}
    if s is not None:  # the tractor: θ and y as 1-D attributes, every setting in the header
        header[CONSTANT_ATTRS["theta_deg"]] = json.dumps([float(x) for x in s.theta_deg])
        header[CONSTANT_ATTRS["y_m"]] = json.dumps([float(x) for x in s.y_m])
        header["simlidar_settings"] = json.dumps(s.to_dict(), sort_keys=True)
        for key, value in s.to_dict().items():
            header[f"scan_{key}"] = header_value(value)
    else:  # other platforms: column angle and row coordinate, the pattern in the header
        header[CONSTANT_ATTRS["angle_deg"]] = json.dumps([float(x) for x in p.col_angle_deg])
        header[CONSTANT_ATTRS["row_coord"]] = json.dumps([float(x) for x in p.row_coord])
        header["simlidar_pattern"] = json.dumps(p.to_dict(), sort_keys=True)
        header["row_coord_label"] = p.row_label
        header["angle_label"] = p.col_label
    if getattr(result, "tree_id", None) is not None:
        dtypes["tree_id"] = np.uint32
    if p.footprint > 0:
        dtypes["hit_fraction"] = np.float32
    if seed is not None:
        header["seed"] = header_value(seed)
    for key, value in (extra or {}).items():
        header[key] = header_value(value)
    return header, with_half_copies(dtypes)


def result_rows(result, a: int, b: int) -> dict[str, np.ndarray]:
    """Rows [a, b) of a held ScanRecord's first-return channels."""
    out = {"range": result.range_m[a:b], "class": result.cls[a:b], "branch_id": result.element_id[a:b],
           "hit_fraction": result.hit_fraction[a:b]}
    if result.tree_id is not None:
        out["tree_id"] = result.tree_id[a:b]
    return out


def write_scan_exr(result: ScanRecord, path: str | Path, *, seed: int | None = None,
                   scene_sha256: str = "", extra: dict | None = None, threads: int = 2) -> Path:
    """Write ``result`` to ``path`` (ZIP compression, scanlines); returns the path.

    ``threads``: compressing threads (:class:`ScanlineExrWriter`); the bytes do not depend on it."""
    header, dtypes = scan_exr_layout(result, seed=seed, scene_sha256=scene_sha256, extra=extra)
    n, m = result.shape
    rows = result_rows(result, 0, n)  # views: the writer converts 16 lines at a time
    if getattr(result, "echoes", None) is not None:
        full: dict = {}
        _echo_channels(result, full, header)
        dtypes = with_half_copies({**dtypes, **{k: v.dtype.type for k, v in full.items()}})
        rows.update(full)
    with atomic_file(path) as tmp, ScanlineExrWriter(tmp, header, dtypes, n, m, threads=threads) as w:
        w.write_rows(rows)
    return Path(path)


class ScanlineExrWriter:
    """A single-part scanline OpenEXR file with ZIP compression, written rows at a time.

    OpenEXR 3.5's ``OpenEXR.File`` writes whole images only (every channel of the scan in
    memory at once), and the deprecated ``OpenEXR.OutputFile``, which writes scanlines,
    stores float attributes as float32 and refuses float64 ones.  So the header is made by
    ``OpenEXR.File`` (a one-row image, its data window then set to N rows) and the pixel
    blocks here, as the EXR format defines them: 16 scanlines per block, each line's channels
    in name order, bytes split into even/odd halves, delta-coded (+128), zlib-deflated (or
    stored raw when that is not smaller), behind a table of block offsets.  Block contents
    depend only on the rows, so the file's bytes do not depend on how rows are fed.

    Speed (issue #8): zlib at level 4 is most of the time and cannot change (it fixes the
    bytes); around it, each block is converted, interleaved and coded in three reused
    buffers of one block per thread (~150 kB: they stay in cache, where whole-scan passes
    and fresh arrays per block ran 3–6× slower), and runs of :attr:`RUN` blocks go to two
    threads (zlib and most numpy loops release the GIL).
    """

    LINES = 16  # scanlines per ZIP block (the EXR format's)
    RUN = 8  # most blocks per task: few tasks, yet a busy core does not hold back the other

    def __init__(self, path, header: dict, dtypes: dict, n_rows: int, n_cols: int, level: int = 4,
                 threads: int = 2):
        self.names = sorted(dtypes, key=lambda k: k.encode())
        # rows give X for a half copy X_half (with_half_copies); other names are their own
        self.source = {k: k[:-len(HALF)] if k.endswith(HALF) and k[:-len(HALF)] in dtypes else k
                       for k in self.names}
        self.dtypes = {k: np.dtype(dtypes[k]).newbyteorder("<") for k in self.names}
        self.n, self.m, self.level = int(n_rows), int(n_cols), level
        # byte columns of each channel within one scanline
        widths = [self.dtypes[k].itemsize * self.m for k in self.names]
        self.spans = [(int(a), int(a + w)) for a, w in zip(np.cumsum([0] + widths[:-1]), widths)]
        self.line_bytes = sum(widths)
        head = _header_bytes(header, self.dtypes, self.n, self.m)
        self.f = open(path, "wb")
        self.f.write(head)
        self.table_at = len(head)
        self.offsets: list[int] = []
        self.f.write(b"\0" * 8 * (-(-self.n // self.LINES)))
        self.pending: dict[str, list] = {k: [] for k in self.names}
        self.buffered = self.row = 0
        from concurrent.futures import ThreadPoolExecutor  # noqa: PLC0415
        # zlib releases the GIL: compress blocks on both cores.  One thread costs 3–5 % less
        # CPU (BENCHMARKS §8f), the better choice when the other core is busy anyway
        self.pool = ThreadPoolExecutor(int(threads)) if threads > 1 else None
        self.scratch = threading.local()  # each thread's block buffers

    def __enter__(self):
        return self

    def __exit__(self, kind, value, tb):
        if kind is None:
            self.close()
        else:
            if self.pool:
                self.pool.shutdown()
            self.f.close()

    def write_rows(self, rows: dict[str, np.ndarray]) -> None:
        """Append rows (every channel of the header but half copies, each (r, M) any castable dtype).

        Whole blocks are written before this returns; the few rows left over are copied,
        so the caller may reuse its arrays."""
        r = len(rows[self.source[self.names[0]]])
        self.buffered += r
        whole = self.buffered // self.LINES * self.LINES
        flush = whole or self.row + self.buffered == self.n
        for k in self.names:  # held until a block fills: copied, fewer than 16 lines
            x = np.asarray(rows[self.source[k]]).reshape(r, self.m)
            self.pending[k].append(x if flush else np.array(x, self.dtypes[k]))
        if flush:
            self._flush(whole if self.row + self.buffered < self.n else self.buffered)

    def _flush(self, count: int) -> None:
        data = [np.concatenate([np.asarray(x, self.dtypes[k]) for x in self.pending[k]])
                if len(self.pending[k]) > 1 else self.pending[k][0] for k in self.names]
        n_blocks = -(-count // self.LINES)  # small flushes (streamed chunks) still split in 4
        step = self.LINES * max(1, min(self.RUN, -(-n_blocks // 4)))
        runs = [(a, min(count, a + step)) for a in range(0, count, step)]
        encode = self.pool.map if self.pool else map
        for (a, _), payloads in zip(runs, encode(lambda run: self._blocks(data, *run), runs)):
            for i, payload in enumerate(payloads):
                self.offsets.append(self.f.tell())
                self.f.write(np.array([self.row + a + i * self.LINES, len(payload)], "<i4").tobytes())
                self.f.write(payload)
        self.row += count
        self.buffered -= count
        self.pending = {k: [np.array(d[count:], self.dtypes[k])] if self.buffered else []
                        for k, d in zip(self.names, data)}

    def _blocks(self, chans: list[np.ndarray], a: int, b: int) -> list[bytes]:
        """The payloads of the blocks of lines [a, b) of ``chans`` (one thread's run)."""
        size = self.LINES * self.line_bytes
        if getattr(self.scratch, "size", None) != size:  # this thread's, reused: stays in cache
            self.scratch.size, self.scratch.bufs = size, [np.empty(size, np.uint8) for _ in range(3)]
        raw, split, pred = self.scratch.bufs
        out = []
        for y in range(a, b, self.LINES):
            lines = min(b, y + self.LINES) - y
            k = lines * self.line_bytes
            # line-interleaved: for each scanline, every channel's row in name order
            grid = raw[:k].reshape(lines, self.line_bytes)
            for (c0, c1), name, c in zip(self.spans, self.names, chans):
                grid[:, c0:c1].view(self.dtypes[name])[...] = c[y:y + lines]
            _predict(raw[:k], split[:k], pred[:k])
            packed = zlib.compress(pred[:k], self.level)
            out.append(packed if len(packed) < k else raw[:k].tobytes())
        return out

    def close(self) -> None:
        if self.row != self.n:
            raise ValueError(f"EXR writer got {self.row} of {self.n} rows")
        if self.pool:
            self.pool.shutdown()
        self.f.seek(self.table_at)
        self.f.write(np.asarray(self.offsets, "<u8").tobytes())
        self.f.close()


def _predict(raw: np.ndarray, split: np.ndarray, pred: np.ndarray) -> None:
    """The EXR ZIP predictor of one block's bytes ``raw`` into ``pred`` (``split``: scratch):
    bytes at even offsets then those at odd ones, each byte minus the one before + 128
    (mod 256; the first byte as it is)."""
    k, h = raw.size, (raw.size + 1) // 2
    if k % 2 == 0:  # as uint16 words the even bytes are the low halves: no strided byte copy
        words = raw.view("<u2")
        np.copyto(split[:h], words, casting="unsafe")  # keeps the low byte
        np.right_shift(words, 8, out=split[h:], casting="unsafe")
    else:
        split[:h] = raw[0::2]
        split[h:] = raw[1::2]
    if k:
        pred[0] = split[0]
    np.subtract(split[1:], split[:-1], out=pred[1:])
    np.bitwise_xor(pred[1:], 128, out=pred[1:])  # + 128 mod 256 flips the top bit


def _header_bytes(header: dict, dtypes: dict, n: int, m: int) -> bytes:
    """Magic, version and attributes of an N × M image, as ``OpenEXR.File`` writes them."""
    import tempfile  # noqa: PLC0415
    with tempfile.TemporaryDirectory() as d:
        one = {k: np.zeros((1, m), t) for k, t in dtypes.items()}
        with OpenEXR.File(dict(header), one) as f:
            f.write(f"{d}/h.exr")
        data = open(f"{d}/h.exr", "rb").read()
    pos, out = 8, bytearray(data[:8])
    while data[pos] != 0:
        name_end = data.index(b"\0", pos)
        type_end = data.index(b"\0", name_end + 1)
        size = int.from_bytes(data[type_end + 1:type_end + 5], "little")
        name = data[pos:name_end]
        value = data[type_end + 5:type_end + 5 + size]
        if name in (b"dataWindow", b"displayWindow"):
            box = np.frombuffer(value, "<i4").copy()
            box[3] = box[1] + n - 1
            value = box.tobytes()
        out += data[pos:type_end + 5] + value
        pos = type_end + 5 + size
    return bytes(out + b"\0")


def _echo_channels(result: ScanRecord, channels: dict, header: dict) -> None:
    """Add the echo channels and the sensor header of a ``[sensor]`` scan (module docstring)."""
    n, m = result.shape
    echoes, sensor = result.echoes, result.sensor
    counts = result.n_returns if result.n_returns is not None else \
        echoes.returns_per_beam(n * m).reshape(n, m)
    channels["n_returns"] = np.ascontiguousarray(counts, np.uint32)
    with_intensity = result.intensity is not None
    if with_intensity:
        channels["intensity"] = np.ascontiguousarray(result.intensity, np.float32)
    max_returns = int((sensor or {}).get("max_returns") or
                      (int(echoes.return_number.max()) if len(echoes) else 1))
    for r in range(2, max_returns + 1):
        layer = echoes.layer((n, m), r, escape_m=result.pattern.escape_m)
        channels[f"echo{r}.range"] = np.ascontiguousarray(layer["range_m"], np.float32)
        channels[f"echo{r}.class"] = np.ascontiguousarray(layer["cls"], np.uint32)
        channels[f"echo{r}.branch_id"] = np.ascontiguousarray(layer["element_id"], np.uint32)
        if with_intensity:
            channels[f"echo{r}.intensity"] = np.ascontiguousarray(layer["intensity"], np.float32)
        if layer["tree_id"] is not None:
            channels[f"echo{r}.tree_id"] = np.ascontiguousarray(layer["tree_id"], np.uint32)
    if sensor is not None:
        header.update(sensor_header(sensor))


def sensor_header(sensor: dict) -> dict:
    """Header attributes of a ``[sensor]`` scan: ``simlidar_sensor`` (the resolved sensor as
    JSON).  The LAS intensity scale is points.las's own (module docstring)."""
    return {"simlidar_sensor": json.dumps(sensor, sort_keys=True, default=_plain)}


def _plain(value):
    """numpy scalars and arrays as JSON values."""
    return value.tolist() if hasattr(value, "tolist") else str(value)


def read_exr(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    """Channels and header of any EXR; JSON-encoded ``simlidar_pattern`` and
    ``simlidar_sensor`` are decoded into ``header['pattern']`` and ``header['sensor']``."""
    try:
        with OpenEXR.File(str(path)) as f:
            header = dict(f.header())  # emptied when the file closes
            channels = {k: np.array(v.pixels) for k, v in f.channels().items()}
    except Exception as exc:  # OpenEXR raises plain exceptions for unreadable files
        raise SimlidarError(f"{path}: cannot read EXR: {exc}") from exc
    if "simlidar_pattern" in header:
        header["pattern"] = json.loads(header["simlidar_pattern"])
    if "simlidar_sensor" in header:
        header["sensor"] = json.loads(header["simlidar_sensor"])
    return channels, header
