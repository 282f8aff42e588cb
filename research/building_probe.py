"""Map a generated building from its ground-truth layouts and score it (the fusion alone, no CLI)."""
import json, sys, time
from pathlib import Path
from layouts.codecs import LayoutFolder
from layouts.locations import read_inventory
from stitching.pipeline import Stitcher
from stitching.building_route import load_route, perturb
from stitching.building_register import place_pass
from stitching.building_fuse import fuse_building
from stitching.building_eval import evaluate_building
from stitching.warehouse_map import WarehouseMap

root = Path(sys.argv[1]); noise = sys.argv[2] if len(sys.argv) > 2 else None
cache = Path(f"/tmp/b/cache_{root.name}"); cache.mkdir(exist_ok=True, parents=True)
route = load_route(root / "route.json")
if noise:
    m, d = map(float, noise.split(",")); route = perturb(route, m, d, 0)
placed = []
t0 = time.time()
for pose in route.passes:
    f = cache / f"{pose.sequence}.json"
    if f.exists():
        wm = WarehouseMap.load(f)
    else:
        folder = LayoutFolder(root / pose.sequence / "layouts")
        st = Stitcher(folder.spec)
        for i in range(folder.num_frames if hasattr(folder, "num_frames") else len(folder)):
            st.push(folder.read(i), i)
        wm = st.map(); wm.save(f)
    placed.append(place_pass(pose, route.faces[pose.key], wm))
t1 = time.time()
b = fuse_building(route, placed)
t2 = time.time()
truth = json.loads((root / "ground_truth/building.json").read_text())
rows = read_inventory((root / "ground_truth/inventory.csv").read_text())
ev = evaluate_building(b, truth, rows)
d = ev.to_dict(); wrong = d.pop("wrong")
print(json.dumps(d, indent=None), f"maps {t1-t0:.1f}s fuse {t2-t1:.2f}s")
for w in wrong[:10]: print(w)
for p in b.passes: print(p.name, p.aisle, p.side, round(p.shift,3), [(e['with'], e['shift'], e['matches']) for e in p.edges])
