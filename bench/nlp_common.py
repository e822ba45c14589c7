"""Shared helpers of the NLP region-search benchmarks: the evaluation set and top-k accuracy."""
import json
from pathlib import Path
from typing import Callable, Dict, List, Sequence

import yaml

ROOT = Path(__file__).resolve().parent.parent
EVAL_FILE = ROOT / "bench" / "data" / "region_eval.yaml"
OUT_DIR = ROOT / "artifacts" / "bench"
BROWN_ZIP = ROOT.parent / "shared" / "data" / "corpora" / "brown.zip"

# rank(phrase, labels) -> labels, best first
Ranker = Callable[[str, Sequence[str]], List[str]]


def load_eval(path: Path = EVAL_FILE) -> Dict[str, dict]:
    """{building: {"labels": [...], "queries": [{phrase, expected, split}]}}; every second query
    of a building (index 1, 3, ...) is held-out "test", as the file says."""
    data = yaml.safe_load(Path(path).read_text())["buildings"]
    for building in data.values():
        for index, query in enumerate(building["queries"]):
            query["split"] = "test" if index % 2 else "dev"
    return data


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
        summary[split] = {"n": len(chosen),
                          "top1": sum(r["top1_ok"] for r in chosen) / len(chosen),
                          "top3": sum(r["top3_ok"] for r in chosen) / len(chosen)}
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
    """Load an embedding backend (region_search.backends.BackendConfig(**config)) in a
    new Python process, imports included, and embed one phrase: what a node's start-up costs.
    Returns {"seconds": total, "load_seconds": the loader's own time, "backend": served, "note"}."""
    import subprocess
    import sys

    code = ("import json, sys, time; t = time.monotonic();"
            "from region_search.backends import BackendConfig, load_backend;"
            "b = load_backend(BackendConfig(**json.loads(sys.argv[1])));"
            "b.embeddings.embed_phrases(['water fountain']);"
            "print(json.dumps({'seconds': time.monotonic() - t, 'load_seconds': b.load_seconds,"
            " 'backend': b.backend, 'note': b.note}))")
    out = subprocess.run([sys.executable, "-c", code, json.dumps(config)], capture_output=True,
                         text=True)
    if out.returncode != 0:
        raise RuntimeError(f"loading {config} failed: {out.stderr.strip()[-500:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])
