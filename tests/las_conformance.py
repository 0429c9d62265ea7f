"""A LAS 1.4 conformance check written from the specification (ASPRS LAS 1.4 R15, 9 July 2019,
https://github.com/ASPRSorg/LAS at tag 1.4.R15), reading the file's bytes with ``struct`` and
numpy only, so that it shares no code with laspy or our writer.

:func:`check_las` returns a list of problems (empty: conformant).  Sections cited:

- §2.4 Public Header Block (table "Public Header Block", field descriptions);
- §2.4 Global Encoding (bits 0-4 defined, 5-15 "must be set to zero");
- §2.2 Coordinate Reference System: point formats 6-10 require the WKT bit ("Error" without);
- §2.5 Variable Length Records (54-byte header, reserved must be 0);
- §2.6 Point Data Record Format 6 (30 bytes; return number, number of returns, scan angle);
- §4 Extra Bytes VLR (LASF_Spec / 4: 192-byte descriptors, data types, options, zero fields).

It also covers the checks of LAStools' ``lasvalidate`` (lascheck.cpp) that apply to these files:
header counts against the points, bounding box against the points, return-number combinations,
scale factors > 0, offsets on the scale's grid ("translation fluff"), coordinate "resolution
fluff" (every stored X, Y or Z with the first one's remainder modulo 10, C's %, as
LASlib/src/lasutility.cpp counts it; a constant axis, which no scale can help, is not reported), GPS week time range when bit 0 is clear,
generating software / system identifier null padding, file creation day and year.
"""
from __future__ import annotations

import datetime
import struct
from pathlib import Path

import numpy as np

HEADER_SIZE_14 = 375          # §2.4 "Header Size": 375 bytes for LAS 1.4
VLR_HEADER_SIZE = 54          # §2.5
PDRF6_SIZE = 30               # §2.6 Point Data Record Format 6
EB_DESCRIPTOR_SIZE = 192      # §4 Extra Bytes: "total of 192 bytes"
EB_TYPE_SIZE = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 8, 8: 8, 9: 4, 10: 8}  # §4 data_type table
EB_NUMPY = {1: "u1", 2: "i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<u8", 8: "<i8", 9: "<f4", 10: "<f8"}
SCAN_ANGLE_LIMIT = 30000      # §2.6 "Scan Angle": ±30,000 (±180°) in 0.006° increments
GPS_WEEK_S = 604800.0         # §2.4 Global Encoding bit 0 clear: GPS Week Time

# §2.4 table "Public Header Block", up to Number of Points by Return (LAS 1.4)
_HEADER = struct.Struct("<4sHHLHH8s BB 32s32s HH HLLBH L5L 3d3d 6d QQLQ15Q")
_HEADER_FIELDS = ("signature", "file_source_id", "global_encoding", "guid1", "guid2", "guid3", "guid4",
                  "version_major", "version_minor", "system_identifier", "generating_software",
                  "creation_day", "creation_year", "header_size", "offset_to_point_data", "number_of_vlrs",
                  "point_format", "record_length", "legacy_point_count",
                  "legacy_by_return0", "legacy_by_return1", "legacy_by_return2", "legacy_by_return3",
                  "legacy_by_return4", "x_scale", "y_scale", "z_scale", "x_offset", "y_offset", "z_offset",
                  "max_x", "min_x", "max_y", "min_y", "max_z", "min_z", "start_of_waveform",
                  "start_of_first_evlr", "number_of_evlrs", "point_count",
                  *(f"by_return{i}" for i in range(15)))
_PDRF6 = np.dtype([("X", "<i4"), ("Y", "<i4"), ("Z", "<i4"), ("intensity", "<u2"), ("returns", "u1"),
                   ("flags", "u1"), ("classification", "u1"), ("user_data", "u1"), ("scan_angle", "<i2"),
                   ("point_source_id", "<u2"), ("gps_time", "<f8")])


def _record_dtype(fields: np.dtype, itemsize: int, at: int = 0) -> np.dtype:
    """``fields`` at byte ``at`` of records of ``itemsize`` bytes."""
    return np.dtype({"names": list(fields.names), "formats": [fields[k] for k in fields.names],
                     "offsets": [at + fields.fields[k][1] for k in fields.names], "itemsize": itemsize})


def _padded_text(raw: bytes, what: str, problems: list) -> str:
    """ASCII text padded with nulls: 'the remaining data must be null' (§2.4, §2.5, §4)."""
    text, _, rest = raw.partition(b"\0")
    if rest.strip(b"\0"):
        problems.append(f"{what}: characters after the terminating null must be null")
    return text.decode("ascii", "replace")


def read_header(data: bytes) -> dict:
    return dict(zip(_HEADER_FIELDS, _HEADER.unpack_from(data, 0)))


def read_vlrs(data: bytes, h: dict, problems: list) -> list[dict]:
    """The VLRs between the header and the points (§2.5)."""
    vlrs, at = [], h["header_size"]
    for j in range(h["number_of_vlrs"]):
        if at + VLR_HEADER_SIZE > h["offset_to_point_data"]:
            problems.append(f"VLR {j}: runs past the offset to point data")
            return vlrs
        reserved, user, rid, length, desc = struct.unpack_from("<H16sHH32s", data, at)
        if reserved != 0:
            problems.append(f"VLR {j}: reserved is {reserved}, must be 0 (§2.5)")
        vlrs.append({"user_id": _padded_text(user, f"VLR {j} user ID", problems), "record_id": rid,
                     "description": _padded_text(desc, f"VLR {j} description", problems),
                     "data": data[at + VLR_HEADER_SIZE: at + VLR_HEADER_SIZE + length]})
        at += VLR_HEADER_SIZE + length
    if at != h["offset_to_point_data"]:
        problems.append(f"offset to point data is {h['offset_to_point_data']}, the header and VLRs end at {at} (§2.4)")
    return vlrs


def extra_bytes(vlrs: list, problems: list) -> list[dict]:
    """The Extra Bytes descriptors (§4), each checked field by field."""
    ebs = [v for v in vlrs if v["user_id"] == "LASF_Spec" and v["record_id"] == 4]
    if len(ebs) > 1:
        problems.append("more than one Extra Bytes VLR")
    if not ebs:
        return []
    raw = ebs[0]["data"]
    if len(raw) % EB_DESCRIPTOR_SIZE:
        problems.append(f"Extra Bytes VLR length {len(raw)} is not a multiple of 192 (§4)")
    out = []
    for j in range(len(raw) // EB_DESCRIPTOR_SIZE):
        d = raw[j * EB_DESCRIPTOR_SIZE:(j + 1) * EB_DESCRIPTOR_SIZE]
        reserved, dtype, options, name, unused = struct.unpack_from("<2sBB32s4s", d, 0)
        no_data, dep1, mn, dep2, mx, dep3 = d[40:48], d[48:64], d[64:72], d[72:88], d[88:96], d[96:112]
        scale, dep4, offset, dep5, desc = d[112:120], d[120:136], d[136:144], d[144:160], d[160:192]
        label = _padded_text(name, f"extra bytes {j} name", problems)
        _padded_text(desc, f"extra bytes {j} description", problems)
        if not label:
            problems.append(f"extra bytes {j}: empty name")
        if any(b.strip(b"\0") for b in (reserved, unused, dep1, dep2, dep3, dep4, dep5)):
            problems.append(f"extra bytes {label!r}: reserved, unused or deprecated bytes not zero (§4)")
        if not (1 <= dtype <= 10 or (dtype == 0 and options > 0)):
            problems.append(f"extra bytes {label!r}: data_type {dtype} is deprecated or reserved (§4)")
        if options >> 5:
            problems.append(f"extra bytes {label!r}: options bits 5-7 are undefined (§4)")
        for bit, field, what in ((0, no_data, "no_data"), (1, mn, "min"), (2, mx, "max"),
                                 (3, scale, "scale"), (4, offset, "offset")):
            if dtype and not options >> bit & 1 and field.strip(b"\0"):
                problems.append(f"extra bytes {label!r}: {what} not zero while its option bit is clear (§4)")
        size = EB_TYPE_SIZE.get(dtype, options if dtype == 0 else 0)
        out.append({"name": label, "data_type": dtype, "size": size})
    return out


def check_las(path: str | Path, *, today: datetime.date | None = None) -> list[str]:
    """Problems of the LAS 1.4 file ``path`` with point format 6 (empty list: conformant)."""
    data = Path(path).read_bytes()
    problems: list[str] = []
    h = read_header(data)
    if h["signature"] != b"LASF":
        return [f"file signature {h['signature']!r}, must be 'LASF' (§2.4)"]
    if (h["version_major"], h["version_minor"]) != (1, 4) or h["header_size"] != HEADER_SIZE_14:
        return [f"not a LAS 1.4 header: version {h['version_major']}.{h['version_minor']}, size {h['header_size']}"]
    if h["point_format"] != 6:
        return [f"point format {h['point_format']}: this check covers format 6 only"]
    _padded_text(h["system_identifier"], "system identifier", problems)
    if not _padded_text(h["generating_software"], "generating software", problems):
        problems.append("generating software is empty")
    today = today or datetime.datetime.now(datetime.timezone.utc).date()
    if not (1990 <= h["creation_year"] <= today.year and 1 <= h["creation_day"] <= 366):
        problems.append(f"file creation day/year {h['creation_day']}/{h['creation_year']} out of range (§2.4)")

    ge = h["global_encoding"]  # §2.4 Global Encoding; §2.2: formats 6-10 need the WKT bit
    if ge >> 5:
        problems.append(f"global encoding {ge:#x}: bits 5-15 are reserved and must be 0")
    if not ge & 16:
        problems.append("global encoding: the WKT bit (4) must be set for point format 6 (§2.2)")
    if ge & 6:
        problems.append("global encoding: waveform bits set for point format 6 (no waveform packets)")
    if h["start_of_waveform"] != 0 and not ge & 2:
        problems.append("start of waveform data packet record must be 0 (bit 1 clear)")

    vlrs = read_vlrs(data, h, problems)
    ebs = extra_bytes(vlrs, problems)
    wkt = [v for v in vlrs if v["user_id"] == "LASF_Projection" and v["record_id"] == 2112]
    if len(wkt) > 1:
        problems.append("more than one WKT CRS record (§2.2)")
    if any(v["user_id"] == "LASF_Projection" and v["record_id"] in (34735, 34736, 34737) for v in vlrs):
        problems.append("GeoTIFF CRS records in a point format 6 file (§2.2: WKT only)")

    # §2.4 Point Data Record Length, §4 "extra bytes mismatch"
    eb_size = sum(e["size"] for e in ebs)
    if h["record_length"] != PDRF6_SIZE + eb_size:
        problems.append(f"point data record length {h['record_length']}, expected 30 + {eb_size} extra bytes")
    # §2.4 legacy counts: zero for point formats >= 6
    legacy = [h["legacy_point_count"]] + [h[f"legacy_by_return{i}"] for i in range(5)]
    if any(legacy):
        problems.append(f"legacy point counts {legacy} must be 0 for point format 6 (§2.4)")
    if h["start_of_first_evlr"] or h["number_of_evlrs"]:
        problems.append("EVLRs present: not expected in these files")

    n = h["point_count"]
    body = len(data) - h["offset_to_point_data"]
    if body != n * h["record_length"]:
        problems.append(f"Number of Point Records {n} does not match the {body} bytes of point data (§2.4)")
        return problems
    for c in "xyz":
        if not h[f"{c}_scale"] > 0:
            problems.append(f"{c} scale factor {h[f'{c}_scale']} must be > 0")
        q = h[f"{c}_offset"] / h[f"{c}_scale"]
        if abs(q - round(q)) > 1e-6:
            problems.append(f"{c} offset {h[f'{c}_offset']!r} is not on the {c} scale's grid (translation fluff)")
    rec = np.frombuffer(data, _record_dtype(_PDRF6, h["record_length"]), count=n, offset=h["offset_to_point_data"])
    ret, nret = rec["returns"] & 15, rec["returns"] >> 4  # §2.6: bits 0-3, 4-7
    bad = np.count_nonzero((ret < 1) | (ret > nret))
    if bad:
        problems.append(f"{bad} points break 1 <= return number <= number of returns (§2.6)")
    counts = np.bincount(ret, minlength=16)[1:16]
    by_return = [h[f"by_return{i}"] for i in range(15)]
    if by_return != counts.tolist():
        problems.append(f"Number of Points by Return {by_return} != the points' {counts.tolist()} (§2.4)")
    if np.any(np.abs(rec["scan_angle"].astype(np.int32)) > SCAN_ANGLE_LIMIT):
        problems.append("scan angle beyond ±30,000 (±180°) (§2.6)")
    gps = rec["gps_time"]
    if n and not np.all(np.isfinite(gps)):
        problems.append("non-finite GPS time")
    if n and not ge & 1 and (gps.min() < 0 or gps.max() > GPS_WEEK_S):
        problems.append(f"GPS week time (bit 0 clear) outside 0 … 604800 s: {gps.min()} … {gps.max()}")
    for c, name in enumerate("XYZ"):  # §2.4 Max and Min: the data's extents
        if not n:
            continue
        v = rec[name].astype(np.int64)
        s, o = h[f"{name.lower()}_scale"], h[f"{name.lower()}_offset"]
        lo, hi = v.min() * s + o, v.max() * s + o
        if abs(h[f"min_{name.lower()}"] - lo) > s / 2 or abs(h[f"max_{name.lower()}"] - hi) > s / 2:
            problems.append(f"header {name} extent [{h[f'min_{name.lower()}']}, {h[f'max_{name.lower()}']}] "
                            f"!= the data's [{lo}, {hi}] (§2.4)")
        if len(v) > 1 and np.any(v != v[0]) and np.all(np.fmod(v, 10) == np.fmod(v[0], 10)):
            problems.append(f"resolution fluff (x10) in {name}: every stored {name} ends in the same digit")
    if ebs and n:  # every descriptor readable at its place in the record
        at = PDRF6_SIZE
        for e in ebs:
            if e["data_type"]:
                field = np.dtype([("v", EB_NUMPY[e["data_type"]])])
                v = np.frombuffer(data, _record_dtype(field, h["record_length"], at), count=n,
                                  offset=h["offset_to_point_data"])["v"]
                if e["data_type"] in (9, 10) and not np.all(np.isfinite(v)):
                    problems.append(f"extra bytes {e['name']!r}: non-finite values")
            at += e["size"]
    return problems


def wkt_text(path: str | Path) -> str | None:
    """The WKT CRS record's text (§2.2, LASF_Projection 2112), or None."""
    data = Path(path).read_bytes()
    problems: list[str] = []
    for v in read_vlrs(data, read_header(data), problems):
        if v["user_id"] == "LASF_Projection" and v["record_id"] == 2112:
            return v["data"].rstrip(b"\0").decode("ascii")
    return None
