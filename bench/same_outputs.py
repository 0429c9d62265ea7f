"""Are two output folders the same data? ``python bench/same_outputs.py BEFORE AFTER``

Every file of BEFORE must exist in AFTER with the same bytes, or else: JSON equal without
``seconds`` keys, CSV equal without a ``seconds`` column, EXR pixels and headers equal without
``seconds``, LAS equal but for the creation day/year (header bytes 90-93). PNG figures may
differ (reported, not counted). Prints the number of differing data files.
"""
import csv, hashlib, json, sys
from pathlib import Path
import numpy as np
A, B = Path(sys.argv[1]), Path(sys.argv[2])
def strip(o):
    if isinstance(o, dict): return {k: strip(v) for k, v in o.items() if k != "seconds"}
    if isinstance(o, list): return [strip(v) for v in o]
    return o
bad = 0
for fa in sorted(p for p in A.rglob("*") if p.is_file()):
    fb = B / fa.relative_to(A)
    rel = fa.relative_to(A)
    if not fb.exists(): print("MISSING", rel); bad += 1; continue
    if fa.read_bytes() == fb.read_bytes(): continue
    if fa.suffix == ".json":
        ok = strip(json.loads(fa.read_text())) == strip(json.loads(fb.read_text()))
    elif fa.suffix == ".csv":
        ra, rb = list(csv.reader(fa.open())), list(csv.reader(fb.open()))
        i = ra[0].index("seconds") if "seconds" in ra[0] else None
        ok = [r[:i] + r[i+1:] if i is not None else r for r in ra] == [r[:i] + r[i+1:] if i is not None else r for r in rb]
    elif fa.suffix == ".exr":
        import OpenEXR
        a, b = OpenEXR.File(str(fa)), OpenEXR.File(str(fb))
        ok = all(np.array_equal(c.pixels, b.channels()[k].pixels) for k, c in a.channels().items())
        ha, hb = a.header(), b.header()
        for k in ha:
            va, vb = ha[k], hb.get(k)
            if isinstance(va, str) and va.startswith("{"):
                va, vb = strip(json.loads(va)), strip(json.loads(vb))
            ok &= str(va) == str(vb)
    elif fa.suffix == ".las":
        da, db = fa.read_bytes(), fb.read_bytes()
        ok = len(da) == len(db) and da[:90] == db[:90] and da[94:] == db[94:]  # creation day/year at 90..93
    elif fa.suffix == ".png":
        print("figure differs (allowed):", rel); continue
    else:
        ok = False
    if not ok: print("DIFFERS", rel); bad += 1
print("files compared:", sum(1 for p in A.rglob('*') if p.is_file()), "differing data files:", bad)
