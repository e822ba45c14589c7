#!/usr/bin/env python3
"""Leave-one-building-out accuracy of region search, both embedding backends, with and without
label descriptions, and the ranking's CPU time per phrase.

    python bench/region_search/nlp_region_accuracy.py [--backends sentence,word2vec]
        [--cache-dir DIR] [--write-weights]

Phrase sets: data/lobo_buildings.yaml (five buildings' label sets: the real Towne/Levine floor
with common rooms, an office building, a hospital ward, a university library, a laboratory
building; everyday phrases, some matching no labelled place; written and committed before any
model ran on them). For each building in turn, every setting (evidence weights, description
offset, no-match threshold: ranking_fit.choose) is chosen on the other four and scored on it.
Reported per backend: forced top-1 on the phrases that have a place, the share of all phrases
answered right with the "no labelled place matches" answer, its recall on phrases without a
place and how often a phrase with a place got it; with and without descriptions; the ranking
of the previous release (its methods, fixed settings) on the same phrases for comparison.
Also on the earlier real-floor phrase sets (data/region_*.yaml; no setting is chosen on them),
with the settings chosen on all five buildings.
`--write-weights` writes those all-building settings to
src/region_search/src/region_search/ranking_weights.yaml (what the nodes ship).
Writes artifacts/bench/nlp_region_accuracy.json and .png.
"""
import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))

from nlp_common import (  # noqa: E402
    OUT_DIR,
    REAL_TEST_2_FILE,
    REAL_TEST_FILE,
    load_lobo,
    load_real_eval,
    wilson,
    write_json,
)
from ranking_fit import Scored, choose, evaluate  # noqa: E402

from region_search.corpora import WordNet  # noqa: E402
from region_search.phrase import PhraseRegionRecommender  # noqa: E402
from region_search.ranking import (  # noqa: E402
    DEFAULT_WEIGHTS_PATH,
    PlaceRecommender,
    RankingWeights,
    SentenceFeatures,
    WordFeatures,
)
from region_search.recommender import Region, RegionRecommender  # noqa: E402
from region_search.sentence import load_sentence_model  # noqa: E402
from region_search.training import Word2VecParams, load_embeddings  # noqa: E402

NEUTRAL = RankingWeights({"name": 1.0})


def regions_of(labels, descriptions: bool):
    described = labels.descriptions if descriptions else {}
    return [Region(name, 0.0, 0.0, description=described.get(name, "")) for name in labels]


def scored_items(recommender: PlaceRecommender, buildings: dict) -> list:
    """Every phrase's evidence (labels with their descriptions: both rows come out at once)."""
    items = []
    for name, building in buildings.items():
        labels = building["labels"]
        recommender.set_regions(regions_of(labels, descriptions=True))
        for query in building["queries"]:
            evidence = recommender.evidence(query["phrase"])
            items.append(Scored(name, query["phrase"],
                                [evidence.names.index(e) for e in query["expected"]],
                                evidence.own, evidence.described, evidence.names))
    return items


def leave_one_out(items: list) -> dict:
    """{building: {"weights", "without", "with"}}: settings chosen on the other buildings."""
    folds = {}
    for held_out in dict.fromkeys(i.building for i in items):
        train = [i for i in items if i.building != held_out]
        test = [i for i in items if i.building == held_out]
        weights = choose(train, chosen_on=f"all but {held_out}")
        folds[held_out] = {"weights": weights.as_dict(),
                           "without": evaluate(test, weights, descriptions=False),
                           "with": evaluate(test, weights, descriptions=True)}
    return folds


def pooled(folds: dict, key: str) -> dict:
    n_place = sum(f[key]["n_place"] for f in folds.values())
    n_none = sum(f[key]["n_none"] for f in folds.values())
    hits = sum(f[key]["top1_hits"] for f in folds.values())
    answered = sum(f[key]["answered"] * (f[key]["n_place"] + f[key]["n_none"])
                   for f in folds.values())
    recall = sum(f[key]["no_match_recall"] * f[key]["n_none"] for f in folds.values())
    false = sum(f[key]["false_no_match"] * f[key]["n_place"] for f in folds.values())
    return {"top1": hits / n_place, "top1_ci95": wilson(hits, n_place), "n_place": n_place,
            "answered": answered / (n_place + n_none), "no_match_recall": recall / n_none,
            "false_no_match": false / n_place, "n_none": n_none}


def other_sets(recommender: PlaceRecommender, weights: RankingWeights) -> dict:
    """Earlier real-floor phrase sets (no setting chosen on them), all-building settings."""
    recommender.weights = weights
    out = {}
    for path in (REAL_TEST_2_FILE, REAL_TEST_FILE):
        for building in load_real_eval(path).values():
            for descriptions in (False, True):
                recommender.set_regions(regions_of(building["labels"], descriptions))
                answers = [recommender.recommend(q["phrase"], 1) for q in building["queries"]]
                hits = sum(bool(a.results) and a.results[0].region.name in q["expected"]
                           for a, q in zip(answers, building["queries"]))
                key = f"{path.name} {'with' if descriptions else 'without'} descriptions"
                out[key] = {"n": len(building["queries"]),
                            "top1_answered": hits / len(building["queries"])}
    return out


def previous_release(backend: str, embeddings, wordnet, buildings: dict) -> dict:
    """Forced top-1 of the previous release's ranking on the phrases that have a place."""
    if backend == "sentence":
        recommender = PhraseRegionRecommender(embeddings.embed_phrases, wordnet=wordnet)
    else:
        recommender = RegionRecommender(embeddings.embed_words, wordnet=wordnet, hubness=True)
    out = {}
    for descriptions in (False, True):
        hits = n = 0
        for building in buildings.values():
            recommender.set_regions(regions_of(building["labels"], descriptions))
            for query in building["queries"]:
                if query["expected"]:
                    n += 1
                    top = recommender.recommend(query["phrase"], 1).results[0].region.name
                    hits += top in query["expected"]
        out["with" if descriptions else "without"] = hits / n
    return out


def cpu_per_phrase(recommender: PlaceRecommender, buildings: dict) -> dict:
    """Process CPU and wall time of recommend(phrase, 3), every phrase (new: not cached)."""
    cpu, wall = [], []
    for building in buildings.values():
        recommender.set_regions(regions_of(building["labels"], descriptions=True))
        for query in building["queries"]:
            phrase = f"{query['phrase']} please"  # a phrase the model has not encoded yet
            start, start_wall = time.process_time(), time.perf_counter()
            recommender.recommend(phrase, 3)
            cpu.append(time.process_time() - start)
            wall.append(time.perf_counter() - start_wall)
    return {"cpu_p50_ms": 1e3 * float(np.percentile(cpu, 50)),
            "cpu_p99_ms": 1e3 * float(np.percentile(cpu, 99)),
            "wall_p50_ms": 1e3 * float(np.percentile(wall, 50)),
            "wall_p99_ms": 1e3 * float(np.percentile(wall, 99)), "n": len(cpu),
            "load_average": os.getloadavg()[0]}


def build(backend: str, args, wordnet):
    if backend == "sentence":
        model = load_sentence_model(cache_size=0)
        return model, SentenceFeatures(model.embed_phrases, wordnet)
    model, _ = load_embeddings("auto", params=Word2VecParams(),
                               cache_dir=args.cache_dir or None, progress=True)
    return model, WordFeatures(model.embed_words, wordnet)


def run_backend(backend: str, args, wordnet, buildings: dict) -> dict:
    print(f"\n== {backend}: evidence for {sum(len(b['queries']) for b in buildings.values())} "
          "phrases", flush=True)
    model, features = build(backend, args, wordnet)
    recommender = PlaceRecommender(features, NEUTRAL)
    items = scored_items(recommender, buildings)
    if args.save_evidence:
        import pickle

        OUT_DIR.mkdir(parents=True, exist_ok=True)
        (OUT_DIR / f"region_evidence_{backend}.pkl").write_bytes(pickle.dumps(items))
    folds = leave_one_out(items)
    shipped = choose(items, chosen_on="all five buildings of data/lobo_buildings.yaml")
    result = {"folds": folds, "pooled": {k: pooled(folds, k) for k in ("without", "with")},
              "shipped": shipped.as_dict(),
              "previous_release": previous_release(backend, model, wordnet, buildings),
              "other_sets": other_sets(recommender, shipped)}
    recommender.weights = shipped
    result["cpu_per_phrase"] = cpu_per_phrase(recommender, buildings)
    return result


def write_weights(results: dict) -> None:
    data = yaml.safe_load(DEFAULT_WEIGHTS_PATH.read_text()) if DEFAULT_WEIGHTS_PATH.is_file() \
        else {}
    data.update({backend: r["shipped"] for backend, r in results.items()})
    header = ("# Ranking settings of region_search, per embedding backend: evidence weights, the\n"
              "# description offset and the no-match threshold (region_search.ranking).\n"
              "# Written by bench/region_search/nlp_region_accuracy.py --write-weights: chosen on\n"
              "# all five buildings of its phrase sets; its leave-one-building-out table says how\n"
              "# well settings chosen this way do on a building they were not chosen on.\n")
    DEFAULT_WEIGHTS_PATH.write_text(header + yaml.safe_dump(data, sort_keys=False))
    print(f"wrote {DEFAULT_WEIGHTS_PATH}")


def report(results: dict) -> None:
    print("\nLeave-one-building-out (settings chosen on the other four buildings):")
    print(f"{'backend':10s} {'held-out building':20s} {'top-1 without':>14s} {'top-1 with':>11s}"
          f" {'answered w/o':>13s} {'answered with':>14s} {'no-match recall':>16s}")
    for backend, r in results.items():
        for building, fold in list(r["folds"].items()) + [("ALL (pooled)", None)]:
            w, d = (fold["without"], fold["with"]) if fold else (r["pooled"]["without"],
                                                                   r["pooled"]["with"])
            print(f"{backend:10s} {building:20s} {w['top1']:14.0%} {d['top1']:11.0%} "
                  f"{w['answered']:13.0%} {d['answered']:14.0%} {w['no_match_recall']:16.0%}")
        p = r["previous_release"]
        print(f"{backend:10s} {'previous release':20s} {p['without']:14.0%} {p['with']:11.0%}")
        c = r["cpu_per_phrase"]
        print(f"{backend}: ranking per phrase (encoding included) CPU p50 {c['cpu_p50_ms']:.1f} ms"
              f" p99 {c['cpu_p99_ms']:.1f} ms, wall p50 {c['wall_p50_ms']:.1f} ms p99 "
              f"{c['wall_p99_ms']:.1f} ms (load average {c['load_average']:.1f})")
        for key, s in r["other_sets"].items():
            print(f"{backend}: {key}: top-1 {s['top1_answered']:.0%} of {s['n']}")
        for building, fold in r["folds"].items():
            for miss in fold["without"]["misses"]:
                print(f"  miss {backend} {building}: {miss['phrase']!r} expected "
                      f"{miss['expected'] or '(no match)'}, got {miss['got']}")


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4))
    buildings = list(next(iter(results.values()))["folds"])
    width = 0.2
    for k, (backend, r) in enumerate(results.items()):
        for j, key in enumerate(("without", "with")):
            values = [r["folds"][b][key]["top1"] for b in buildings]
            ax.bar(np.arange(len(buildings)) + (2 * k + j - 1.5) * width, values, width,
                   label=f"{backend}, {key} descriptions")
    ax.axhline(0.9, color="k", lw=0.8, ls="--")
    ax.set_xticks(np.arange(len(buildings)))
    ax.set_xticklabels(buildings, fontsize=8)
    ax.set_ylabel("top-1 on the held-out building")
    ax.set_ylim(0, 1)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--backends", default="sentence,word2vec")
    parser.add_argument("--cache-dir", default="", help="word2vec model cache ('' = default)")
    parser.add_argument("--write-weights", action="store_true")
    parser.add_argument("--save-evidence", action="store_true",
                        help="also pickle every phrase's evidence under artifacts/bench")
    args = parser.parse_args(argv)
    wordnet = WordNet()
    buildings = load_lobo()
    results = {b: run_backend(b, args, wordnet, buildings) for b in args.backends.split(",")}
    report(results)
    path = write_json("nlp_region_accuracy", {"results": results,
                                              "load_average": os.getloadavg()})
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    plot(results, OUT_DIR / "nlp_region_accuracy.png")
    print(f"\nwrote {path} and {OUT_DIR / 'nlp_region_accuracy.png'}")
    if args.write_weights:
        write_weights(results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
