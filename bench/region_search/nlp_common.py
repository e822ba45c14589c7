"""Shared helpers of the NLP region-search benchmarks: the evaluation set and top-k accuracy."""
import json
import math
import os
from pathlib import Path
from typing import Callable, Dict, List, Sequence, Tuple

import yaml

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).resolve().parent / "data"
# The leave-one-building-out phrase sets (five buildings' label sets; written before any run).
LOBO_FILE = DATA / "lobo_buildings.yaml"
EVAL_FILE = DATA / "region_eval.yaml"
# Phrases over the labels of a real floor (GRASP-ML's Towne/Levine labels): a dev
# set (the settings are chosen on it and on region_eval.yaml).
REAL_EVAL_FILE = DATA / "region_eval_real.yaml"
# The first held-out test set (149 phrases over the same floor); run once, its misses were
# read, so it has been a dev set since.
REAL_TEST_FILE = DATA / "region_test_real.yaml"
# The second held-out test set: 168 new phrases over the same floor, written
# before anything was run on them; never used for a choice (run once, at the end).
REAL_TEST_2_FILE = DATA / "region_test_real_2.yaml"
# Label descriptions (what a visitor's sign says), for label files we cannot edit: by label file.
DESCRIPTION_FILES = {"towne_levine_labels.json": ROOT / "src" / "region_search" / "config"
                     / "towne_levine_descriptions.yaml"}
OUT_DIR = ROOT / "artifacts" / "bench"
SHARED_DATA = Path(os.environ.get("SHARED_DATA_DIR", str(ROOT.parent / "shared" / "data")))
SHARED_MAPS = SHARED_DATA / "maps"
BROWN_ZIP = SHARED_DATA / "corpora" / "brown.zip"

# rank(phrase, labels) -> labels, best first
Ranker = Callable[[str, Sequence[str]], List[str]]


class DescribedLabels(list):
    """A building's label names, with `descriptions` ({label: text}, possibly empty) that the
    rankers may use (the recommenders' label descriptions)."""

    def __init__(self, names, descriptions=None):
        super().__init__(names)
        self.descriptions = dict(descriptions or {})


def load_lobo(path: Path = LOBO_FILE) -> Dict[str, dict]:
    """{building: {"labels": DescribedLabels, "queries": [{phrase, expected}]}} of the
    leave-one-building-out file; `expected` [] means no labelled place matches."""
    data = yaml.safe_load(Path(path).read_text())["buildings"]
    for name, building in data.items():
        labels = list(building.get("labels", []))
        if "labels_file" in building:
            labels += sorted(json.loads((SHARED_MAPS / building.pop("labels_file")).read_text()))
        labels += building.pop("extra_labels", [])
        building["labels"] = DescribedLabels(labels, building.pop("descriptions", {}))
        for query in building["queries"]:
            query["split"] = "test"
            missing = set(query["expected"]) - set(labels)
            if missing:
                raise ValueError(f"{path}: {name}: bad query {query} (unknown {missing})")
    return data


def load_eval(path: Path = EVAL_FILE) -> Dict[str, dict]:
    """{building: {"labels": [...], "queries": [{phrase, expected, split}]}}; every second query
    of a building (index 1, 3, ...) is held-out "test", as the file says."""
    data = yaml.safe_load(Path(path).read_text())["buildings"]
    for building in data.values():
        for index, query in enumerate(building["queries"]):
            query["split"] = "test" if index % 2 else "dev"
    return data


def load_real_eval(path: Path = REAL_EVAL_FILE) -> Dict[str, dict]:
    """Like load_eval for a file whose buildings name a map_labelling `labels_file` (in
    ../shared/data/maps, or $SHARED_DATA_DIR/maps)
    and whose queries carry their own `split` (kept as written)."""
    data = yaml.safe_load(Path(path).read_text())["buildings"]
    for building in data.values():
        labels_file = building.pop("labels_file")
        labels = json.loads((SHARED_MAPS / labels_file).read_text())
        descriptions = (yaml.safe_load(DESCRIPTION_FILES[labels_file].read_text())
                        if labels_file in DESCRIPTION_FILES else {})
        building["labels"] = DescribedLabels(sorted(labels), descriptions)
        for query in building["queries"]:
            missing = set(query["expected"]) - set(labels)
            if missing or query.get("split") not in ("dev", "test"):
                raise ValueError(f"{path}: bad query {query} (unknown labels {sorted(missing)})")
    return data


def load_dev_sets(with_first_test: bool = True) -> Dict[str, Dict[str, dict]]:
    """The phrase sets settings are chosen on, every query marked `dev`: the earlier real-floor
    phrases (region_eval_real.yaml), all of region_eval.yaml (five other buildings) and, since
    the second held-out set (`with_first_test`), the first real-floor test set
    (region_test_real.yaml, whose answers have been seen)."""
    sets = {"real floor dev (region_eval_real.yaml)": load_real_eval(REAL_EVAL_FILE),
            "region_eval.yaml (all)": load_eval()}
    if with_first_test:
        sets["real floor, first test set, now dev (region_test_real.yaml)"] = load_real_eval(
            REAL_TEST_FILE)
    for buildings in sets.values():
        for building in buildings.values():
            for query in building["queries"]:
                query["split"] = "dev"
    return sets


def wilson(successes: int, n: int, z: float = 1.959964) -> Tuple[float, float]:
    """95% Wilson score interval of a proportion (successes of n)."""
    if n == 0:
        return float("nan"), float("nan")
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def evaluate(rank: Ranker, buildings: Dict[str, dict]) -> dict:
    """top-1 / top-3 accuracy on dev, test and all queries, plus each query's ranking."""
    rows = []
    for name, building in buildings.items():
        for query in building["queries"]:
            ranking = list(rank(query["phrase"], building["labels"]))
            expected = set(query["expected"])
            rows.append({"building": name, "phrase": query["phrase"], "split": query["split"],
                         "expected": query["expected"], "top3": ranking[:3],
                         "top1_ok": bool(ranking[:1]) and ranking[0] in expected,
                         "top3_ok": bool(expected & set(ranking[:3]))})
    summary = {}
    for split in ("dev", "test", "all"):
        chosen = [r for r in rows if split == "all" or r["split"] == split]
        if not chosen:
            continue
        hits1, hits3 = sum(r["top1_ok"] for r in chosen), sum(r["top3_ok"] for r in chosen)
        summary[split] = {"n": len(chosen), "top1": hits1 / len(chosen),
                          "top3": hits3 / len(chosen), "top1_hits": hits1, "top3_hits": hits3,
                          "top1_ci95": wilson(hits1, len(chosen)),
                          "top3_ci95": wilson(hits3, len(chosen))}
    return {"summary": summary, "queries": rows}


def write_json(name: str, data: dict) -> Path:
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    path = OUT_DIR / f"{name}.json"
    path.write_text(json.dumps(data, indent=2))
    return path


def percentile(values: Sequence[float], q: float) -> float:
    ordered = sorted(values)
    if not ordered:
        return float("nan")
    index = min(len(ordered) - 1, max(0, int(round(q / 100.0 * (len(ordered) - 1)))))
    return ordered[index]


def fresh_process_load_seconds(**config) -> dict:
    """Load an embedding backend (region_search.backends.EmbeddingServerParams(**config)) in a
    new Python process, imports included, and embed one phrase: what a node's start-up costs.
    Returns {"seconds": total, "load_seconds": the loader's own time, "cpu_seconds" (user +
    sys), "max_rss_mb" (peak resident memory), "backend": served, "note"}."""
    import subprocess
    import sys

    code = ("import json, resource, sys, time; t = time.monotonic();"
            "from region_search.backends import EmbeddingServerParams, load_backend;"
            "b = load_backend(EmbeddingServerParams(**json.loads(sys.argv[1])));"
            "b.embeddings.embed_phrases(['water fountain']);"
            "u = resource.getrusage(resource.RUSAGE_SELF);"
            "print(json.dumps({'seconds': time.monotonic() - t, 'load_seconds': b.load_seconds,"
            " 'cpu_seconds': u.ru_utime + u.ru_stime, 'max_rss_mb': u.ru_maxrss / 1024.0,"
            " 'backend': b.backend, 'note': b.note}))")
    out = subprocess.run([sys.executable, "-c", code, json.dumps(config)], capture_output=True,
                         text=True)
    if out.returncode != 0:
        raise RuntimeError(f"loading {config} failed: {out.stderr.strip()[-500:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])
