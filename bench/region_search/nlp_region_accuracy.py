#!/usr/bin/env python3
"""Accuracy of the region recommender on bench/data/region_eval.yaml, and model load times.

Variants (each: top-1 / top-3 on the dev half, the held-out test half and all queries):
- string baseline: label names ranked by spelling similarity alone;
- WordNet lexical: WordNet-expanded labels, exact word matches only (no vectors);
- the sentence backend (all-MiniLM-L6-v2, the product default), in this process:
  names/phrase (cosine of the phrase's and the label name's vectors), expanded/phrase (label
  name + its WordNet words as one text, numbers matched exactly: the default before issue 18),
  that + the bare-name share and the name-spelling stage (issue 18: the product default), the
  same without them with numbers as text only, and the word-level method of the
  word2vec backend run on the sentence model's word vectors (expanded/align+spelling+hubness);
- word2vec on Brown, on WordNet glosses, on Brown + glosses (the fallback), each with
  names/mean (the original approach: cosine of mean vectors of the label-name words),
  names/align (each query word's best label word), names/align+spelling,
  expanded/align+spelling (labels expanded with WordNet synonyms, related words, definitions),
  ... +query expansion (query words also matched through their WordNet words),
  ... +hubness (each label's mean match with the other labels' words subtracted: the word2vec
  default before issue 18), that with raw vectors (no common-direction removal), and
  ... +hubness + name share (half the score on the bare names: the word2vec default).
Variants before issue 18 keep their settings (name_text_weight / name_spelling_weight 0). Since
issue 18 all of region_eval.yaml is a dev set (its test half's figures are no longer held out).
Also: word2vec training time, and each backend's load time in a fresh process (imports included).

    python bench/nlp_region_accuracy.py [--quick] [--brown PATH] [--retrain]

Writes artifacts/bench/nlp_region_accuracy.json and nlp_region_accuracy.png.

    python bench/nlp_region_accuracy.py --shipped [--cache-dir DIR] [--with-brown [--brown PATH]]

The shipped configurations only, as the nodes run them (the sentence backend with the phrase
method; word2vec with `source` auto: Brown + WordNet glosses when a Brown corpus is found
(NLTK's places, or --brown with --with-brown; the 2026-11-25 run of "auto" found the shared
Brown zip through a search that was dropped after it), and the WordNet glosses alone, what a
robot without Brown gets; word method with WordNet labels and hubness), each with
the real floor's label descriptions (src/region_search/config/towne_levine_descriptions.yaml)
and without, plus the settings of issue 18's first round for comparison, on the held-out test
set bench/data/region_test_real_2.yaml (168 phrases over the labels of a real floor, written
before anything ran on them, never used for a choice), top-1 / top-3 with 95% Wilson intervals;
also on the dev sets, marked as such. Writes artifacts/bench/nlp_region_accuracy_shipped.json
and .png (the test rows).

    python bench/nlp_region_accuracy.py --dev2 [--quick] [--cache-dir DIR]

Issue 18's second round, on the dev sets only (region_eval_real.yaml, region_eval.yaml and the
first real-floor test set region_test_real.yaml, whose answers had been seen): numbers said as
words, label descriptions (expanded with WordNet or not, their weight) and the name shares of
both methods; prints every variant's dev figures and the best of each family. Writes
artifacts/bench/nlp_region_accuracy_dev_round2.json.

    python bench/nlp_region_accuracy.py --dev [--cache-dir DIR]

Issue 18's choice of settings, on the dev sets only (nlp_common.load_dev_sets: the earlier 40
real-floor phrases and all of region_eval.yaml): a grid of the sentence phrase method's
name_text_weight x name_spelling_weight, and of the word method's name_text_weight (it matches
names by spelling already); the best by pooled dev top-1 (ties: top-3, then the smaller
weights) is what the code ships. Writes artifacts/bench/nlp_region_accuracy_dev.json.
`--shipped` then reports the shipped settings on the held-out test set
bench/data/region_test_real.yaml (149 phrases, never used for a choice), with the settings before
issue 18 for comparison, and on the dev sets (marked as such).
"""
import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from nlp_common import (
    BROWN_ZIP,
    OUT_DIR,
    REAL_TEST_2_FILE,
    evaluate,
    fresh_process_load_seconds,
    load_dev_sets,
    load_eval,
    load_real_eval,
    wilson,
    write_json,
)

from region_search.corpora import WordNet
from region_search.embeddings import WordEmbeddings
from region_search.phrase import PhraseRegionRecommender
from region_search.recommender import ExpansionWeights, Region, RegionRecommender
from region_search.sentence import load_sentence_model
from region_search.text_similarity import content_words, string_baseline_score, tokenize
from region_search.training import Word2VecParams, load_embeddings

PRODUCT = "sentence expanded/phrase + name share + name spelling"
FALLBACK = "brown+wordnet expanded/align+spelling+hubness + name share"
# The variants measured before issue 18 keep their settings (no bare-name share or spelling).
BEFORE = {"name_text_weight": 0.0}


def recommender_ranker(recommender: RegionRecommender, descriptions: bool = False):
    """rank(phrase, labels); `descriptions`: give the regions the labels' descriptions (when the
    set has any: nlp_common.DescribedLabels)."""
    def rank(phrase, labels):
        described = getattr(labels, "descriptions", {}) if descriptions else {}
        recommender.set_regions([Region(name, 0.0, 0.0, description=described.get(name, ""))
                                 for name in labels])
        return [r.region.name for r in recommender.recommend(phrase, top_k=0).results]
    return rank


def string_ranker(phrase, labels):
    words = content_words(phrase)
    return sorted(labels, key=lambda name: (-string_baseline_score(words, tokenize(name)), name))


def embedding_variants(embeddings, wordnet, raw):
    embed = embeddings.embed_words
    return {
        "names/mean": RegionRecommender(embed, use_spelling=False, method="mean"),
        "names/align": RegionRecommender(embed, use_spelling=False),
        "names/align+spelling": RegionRecommender(embed),
        "expanded/align+spelling": RegionRecommender(embed, wordnet=wordnet, **BEFORE),
        "expanded/align+spelling+query expansion": RegionRecommender(
            embed, wordnet=wordnet, expand_query=True, **BEFORE),
        "expanded/align+spelling+hubness": RegionRecommender(embed, wordnet=wordnet, hubness=True,
                                                             **BEFORE),
        "expanded/align+spelling+hubness, raw vectors": RegionRecommender(
            raw.embed_words, wordnet=wordnet, hubness=True, **BEFORE),
        "expanded/align+spelling+hubness + name share": RegionRecommender(
            embed, wordnet=wordnet, hubness=True),
    }


def sentence_variants(wordnet):
    """The sentence model's variants (the model loaded once, in this process)."""
    start = time.monotonic()
    sentence = load_sentence_model()
    load_seconds = time.monotonic() - start
    before = {"name_text_weight": 0.0, "name_spelling_weight": 0.0}
    variants = {
        "sentence names/phrase": PhraseRegionRecommender(sentence.embed_phrases, **before),
        "sentence expanded/phrase, numbers as text only": PhraseRegionRecommender(
            sentence.embed_phrases, wordnet=wordnet, number_weight=0.0, **before),
        "sentence expanded/phrase": PhraseRegionRecommender(sentence.embed_phrases,
                                                            wordnet=wordnet, **before),
        PRODUCT: PhraseRegionRecommender(sentence.embed_phrases, wordnet=wordnet),
        "sentence expanded/align+spelling+hubness (word level)": RegionRecommender(
            sentence.embed_words, wordnet=wordnet, hubness=True, **BEFORE),
    }
    return sentence, load_seconds, variants


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="word2vec on WordNet glosses only (no Brown variants)")
    parser.add_argument("--brown", default=str(BROWN_ZIP), help="Brown corpus (zip or folder)")
    parser.add_argument("--retrain", action="store_true",
                        help="train into a fresh temporary cache (measures training time)")
    parser.add_argument("--shipped", action="store_true",
                        help="only the two shipped configurations, on the held-out test sets, "
                             "with 95%% Wilson intervals")
    parser.add_argument("--dev", action="store_true",
                        help="choose the issue-18 settings on the dev sets (a grid)")
    parser.add_argument("--dev2", action="store_true",
                        help="issue 18 round 2: descriptions, spoken numbers, weights on the dev "
                             "sets (with --quick: word2vec on WordNet glosses only)")
    parser.add_argument("--sources", default="wordnet,brown+wordnet",
                        help="--dev2: the word2vec corpora to compare (comma-separated)")
    parser.add_argument("--shipped-sources", default="auto,wordnet",
                        help="--shipped: the word2vec sources to report (comma-separated)")
    parser.add_argument("--skip-sentence", action="store_true",
                        help="--shipped: word2vec configurations only")
    parser.add_argument("--with-brown", action="store_true",
                        help="--shipped: word2vec auto with --brown (default: only a Brown corpus "
                             "found where NLTK looks, as the nodes' default brown_path '')")
    parser.add_argument("--cache-dir", default="",
                        help="--shipped: word2vec model cache ('' = the default cache)")
    args = parser.parse_args()
    if args.shipped:
        return shipped(args)
    if args.dev:
        return dev_choice(args)
    if args.dev2:
        return dev_round2(args)
    buildings = load_eval()
    n_queries = sum(len(b["queries"]) for b in buildings.values())
    print(f"evaluation set: {n_queries} queries over {len(buildings)} buildings "
          f"({sum(len(b['labels']) for b in buildings.values())} labels)")
    wordnet = WordNet()
    results, models = {}, {}
    results["string baseline"] = evaluate(string_ranker, buildings)
    results["WordNet lexical (no vectors)"] = evaluate(
        recommender_ranker(RegionRecommender(None, wordnet=wordnet)), buildings)
    sentence, in_process_load, variants = sentence_variants(wordnet)
    for variant, recommender in variants.items():
        results[variant] = evaluate(recommender_ranker(recommender), buildings)
    models["sentence"] = {"description": sentence.description, "dimension": sentence.dimension,
                          "in_process_load_seconds": in_process_load,
                          "fresh_process": fresh_process_load_seconds(backend="sentence")}
    sources = ["wordnet"] if args.quick else ["brown", "wordnet", "brown+wordnet"]
    cache_dir = tempfile.mkdtemp(prefix="nlp_bench_cache_") if args.retrain else None
    params = Word2VecParams()
    for source in sources:
        embeddings, info = load_embeddings(source, brown_path=args.brown, params=params,
                                           cache_dir=cache_dir, progress=True)
        meta = json.loads((Path(info["path"]) / "meta.json").read_text())
        models[source] = {"words": len(embeddings), "dimension": embeddings.dimension,
                          "tokens": meta["tokens"], "train_seconds": meta["train_seconds"],
                          "trained_now": not info["cache_hit"], "first_load_seconds": info["seconds"],
                          "fresh_process": fresh_process_load_seconds(
                              backend="word2vec", source=source, brown_path=args.brown,
                              cache_dir=cache_dir or "")}
        raw = WordEmbeddings(embeddings.kv, counts=embeddings.probabilities,
                             base_forms=embeddings.base_forms, remove_components=-1)
        for variant, recommender in embedding_variants(embeddings, wordnet, raw).items():
            results[f"{source} {variant}"] = evaluate(recommender_ranker(recommender), buildings)
    report(results, models)
    path = write_json("nlp_region_accuracy", {
        "queries": n_queries, "params": vars(params), "models": models,
        "results": results, "product_variant": PRODUCT, "fallback_variant": FALLBACK,
        "quick": args.quick, "load_average": os.getloadavg()})
    plot(results, OUT_DIR / "nlp_region_accuracy.png")
    print(f"\nwrote {path} and {OUT_DIR / 'nlp_region_accuracy.png'}")
    return 0


def summarize(rows) -> dict:
    """n, top-1 / top-3 and their 95% Wilson intervals of evaluated query rows."""
    hits1, hits3 = sum(r["top1_ok"] for r in rows), sum(r["top3_ok"] for r in rows)
    return {"n": len(rows), "top1": hits1 / len(rows), "top3": hits3 / len(rows),
            "top1_hits": hits1, "top3_hits": hits3, "top1_ci95": wilson(hits1, len(rows)),
            "top3_ci95": wilson(hits3, len(rows))}


def shipped_recommenders(args, wordnet):
    """{name: (recommender, use the label descriptions)} of the shipped configurations (the
    nodes' defaults) and the word2vec load infos. word2vec: `source` auto as the node runs it
    (Brown + WordNet glosses when a Brown corpus is found: NLTK's places, or --brown with
    --with-brown) and WordNet glosses alone (a robot without Brown)."""
    sentence = None if args.skip_sentence else load_sentence_model()
    brown = args.brown if args.with_brown else ""  # "": where the node looks (find_brown)
    infos = {}
    word2vec = {}
    for source in args.shipped_sources.split(","):
        embeddings, info = load_embeddings(source, brown_path=brown, params=Word2VecParams(),
                                           cache_dir=args.cache_dir or None, progress=True)
        corpora = "+".join(info["corpora"])
        if corpora in word2vec:
            continue
        infos[corpora] = info
        word2vec[corpora] = (embeddings, "auto = " + corpora if source == "auto"
                             else corpora + " (robot without Brown)")
    configs = {} if args.skip_sentence else {
        "sentence (phrase method)": (PhraseRegionRecommender(sentence.embed_phrases,
                                                             wordnet=wordnet), True),
        "sentence, no label descriptions": (PhraseRegionRecommender(sentence.embed_phrases,
                                                                    wordnet=wordnet), False),
        # For comparison only (nothing is chosen from it): round 1 of issue 18.
        "sentence, round-1 settings": (PhraseRegionRecommender(
            sentence.embed_phrases, wordnet=wordnet, number_words=False, **ROUND1_SENTENCE),
            False),
    }
    for embeddings, title in word2vec.values():
        configs[f"word2vec {title}"] = (RegionRecommender(
            embeddings.embed_words, wordnet=wordnet, hubness=True), True)
        configs[f"word2vec {title.split(' (')[0]}, no label descriptions"] = (RegionRecommender(
            embeddings.embed_words, wordnet=wordnet, hubness=True), False)
        configs[f"word2vec {title.split(' (')[0]}, round-1 settings"] = (RegionRecommender(
            embeddings.embed_words, wordnet=wordnet, hubness=True, number_words=False,
            **round1_word()), False)
    return configs, infos, sentence


def shipped(args) -> int:
    """The shipped configurations on the held-out test set (see the module docstring)."""
    wordnet = WordNet()
    configs, infos, sentence = shipped_recommenders(args, wordnet)
    sets = {"held-out test: real floor, region_test_real_2.yaml": load_real_eval(REAL_TEST_2_FILE)}
    sets.update({f"dev (settings chosen here): {name}": buildings
                 for name, buildings in load_dev_sets().items()})
    table, rows = {}, {}
    for config, (recommender, described) in configs.items():
        ranker = recommender_ranker(recommender, descriptions=described)
        for name, buildings in sets.items():
            rows[(config, name)] = evaluate(ranker, buildings)["queries"]
            table[(config, name)] = summarize(rows[(config, name)])
    print(f"\n{'configuration':58s} {'set':60s} {'n':>3s}  {'top-1 (95% CI)':>20s}  "
          f"{'top-3 (95% CI)':>20s}")
    for (config, name), s in table.items():
        cells = [f"{s[k]:4.0%} ({s[k + '_ci95'][0]:3.0%}-{s[k + '_ci95'][1]:4.0%})"
                 for k in ("top1", "top3")]
        print(f"{config:58s} {name:60s} {s['n']:3d}  {cells[0]:>20s}  {cells[1]:>20s}")
    cpu = cpu_per_query({c: r for c, (r, _) in configs.items()}, sets)
    print("\nin-process CPU time per recommendation (all the sets' phrases, configurations "
          f"interleaved, load average {os.getloadavg()[0]:.1f}):")
    for config, figures in cpu.items():
        print(f"  {config:44s} p50 {figures['p50_ms']:6.2f} ms  p99 {figures['p99_ms']:6.2f} ms")
    for (config, name), queries in rows.items():
        misses = [r for r in queries if not r["top1_ok"]]
        print(f"\n{config}, {name}: {len(misses)} top-1 misses")
        for row in misses:
            print(f"  {row['phrase']!r}: expected {row['expected']}, got {row['top3']}")
    stem = "nlp_region_accuracy_shipped" + ("_word2vec" if args.skip_sentence else "")
    path = write_json(stem, {
        "table": [dict(config=c, set=n, **s) for (c, n), s in table.items()],
        "queries": [dict(config=c, set=n, **r) for (c, n), q in rows.items() for r in q],
        "word2vec": {c: {k: info[k] for k in ("corpora", "path", "cache_hit")}
                     for c, info in infos.items()}, "cpu_per_query": cpu,
        "sentence": sentence.description if sentence else None,
        "load_average": os.getloadavg()})
    plot_shipped({k: v for k, v in table.items() if k[1].startswith("held-out")},
                 OUT_DIR / f"{stem}.png")
    print(f"\nwrote {path} and {OUT_DIR / (stem + '.png')}")
    return 0


def cpu_per_query(configs, sets) -> dict:
    """{config: {"p50_ms", "p99_ms", "n"}}: process CPU time of recommend(phrase, 3) over every
    phrase of the sets (labels set first), the configurations interleaved so that they share the
    machine's load alike."""
    import numpy as np

    times = {config: [] for config in configs}
    for buildings in sets.values():
        for building in buildings.values():
            regions = [Region(name, 0.0, 0.0) for name in building["labels"]]
            for recommender in configs.values():
                recommender.set_regions(regions)
            for query in building["queries"]:
                for config, recommender in configs.items():
                    start = time.process_time()
                    recommender.recommend(query["phrase"], 3)
                    times[config].append(time.process_time() - start)
    return {config: {"p50_ms": 1e3 * float(np.percentile(values, 50)),
                     "p99_ms": 1e3 * float(np.percentile(values, 99)), "n": len(values)}
            for config, values in times.items()}


# The settings of issue 18's first round (kept for the comparison rows).
ROUND1_SENTENCE = {"name_text_weight": 0.3, "name_spelling_weight": 0.2, "number_weight": 0.2}


def round1_word() -> dict:
    return {"name_text_weight": 0.5, "weights": ExpansionWeights(
        name=1.0, synonym=0.9, derived=0.8, definition=0.6, senses=2)}


def dev_round2(args) -> int:
    """Issue 18, second round: label descriptions, spoken numbers and the weights, chosen on the
    dev sets only (region_eval_real.yaml, region_eval.yaml, region_test_real.yaml); the new
    held-out region_test_real_2.yaml is not read here. Best pooled dev top-1 (ties: top-3)."""
    wordnet = WordNet()
    sets = load_dev_sets()
    sentence = load_sentence_model()
    candidates = []  # (family, settings text, recommender, use descriptions)
    candidates.append(("sentence", "round 1", PhraseRegionRecommender(
        sentence.embed_phrases, wordnet=wordnet, number_words=False, **ROUND1_SENTENCE), False))
    candidates.append(("sentence", "round 1 + number words", PhraseRegionRecommender(
        sentence.embed_phrases, wordnet=wordnet, **ROUND1_SENTENCE), False))
    for text_weight in (0.0, 0.3, 0.5, 0.7):
        for spelling_weight in (0.1, 0.2, 0.3):
            for expand in (True, False):
                weights = ExpansionWeights(expand_description=expand)
                candidates.append((
                    "sentence", f"numbers + descriptions (expand {expand}), name_text "
                    f"{text_weight}, name_spelling {spelling_weight}",
                    PhraseRegionRecommender(sentence.embed_phrases, wordnet=wordnet,
                                            weights=weights, name_text_weight=text_weight,
                                            name_spelling_weight=spelling_weight), True))
    corpora = (["wordnet"] if args.quick else
               [c for c in args.sources.split(",") if c])
    for source in corpora:
        embeddings, _ = load_embeddings(source, brown_path=args.brown if "brown" in source else "",
                                        params=Word2VecParams(), cache_dir=args.cache_dir or None,
                                        progress=True)
        family = f"word2vec {source}"
        embed = embeddings.embed_words
        candidates.append((family, "round 1", RegionRecommender(
            embed, wordnet=wordnet, hubness=True, number_words=False, **round1_word()), False))
        candidates.append((family, "round 1 + number words", RegionRecommender(
            embed, wordnet=wordnet, hubness=True, **round1_word()), False))
        for text_weight in (0.3, 0.5, 0.7):
            for expand in (True, False):
                for described in (0.8, 1.0):
                    weights = ExpansionWeights(expand_description=expand, description=described)
                    candidates.append((
                        family, f"numbers + descriptions (expand {expand}, weight {described}), "
                        f"name_text {text_weight}", RegionRecommender(
                            embed, wordnet=wordnet, hubness=True, weights=weights,
                            name_text_weight=text_weight), True))
    results = []
    for family, settings, recommender, described in candidates:
        ranker = recommender_ranker(recommender, descriptions=described)
        per_set = {name: evaluate(ranker, buildings)["queries"] for name, buildings in sets.items()}
        pooled = summarize([r for rows in per_set.values() for r in rows])
        results.append({"family": family, "settings": settings, "pooled": pooled,
                        "sets": {name: summarize(rows) for name, rows in per_set.items()},
                        "misses": [r for rows in per_set.values() for r in rows
                                   if not r["top1_ok"]]})
        cells = "  ".join(f"{summarize(rows)['top1']:4.0%}/{summarize(rows)['top3']:4.0%}"
                          for rows in per_set.values())
        print(f"{family:22s} {settings:78s} {cells}  pooled {pooled['top1']:.1%} / "
              f"{pooled['top3']:.1%}", flush=True)
    print("\nsets: " + " | ".join(sets))
    for family in dict.fromkeys(r["family"] for r in results):
        ranked = sorted((r for r in results if r["family"] == family),
                        key=lambda r: (-r["pooled"]["top1"], -r["pooled"]["top3"]))
        print(f"best for {family}: {ranked[0]['settings']} (dev top-1 "
              f"{ranked[0]['pooled']['top1']:.1%}, top-3 {ranked[0]['pooled']['top3']:.1%})")
    path = write_json("nlp_region_accuracy_dev_round2", {"sets": list(sets), "results": results})
    print(f"\nwrote {path}")
    return 0


# The grids of issue 18's settings (chosen on the dev sets only).
NAME_TEXT_WEIGHTS = (0.0, 0.3, 0.5, 0.7, 1.0)
NAME_SPELLING_WEIGHTS = (0.0, 0.2, 0.3, 0.5, 0.8)


def dev_choice(args) -> int:
    """Grid of the issue-18 settings on the dev sets; prints and writes the best of each method."""
    wordnet = WordNet()
    sets = load_dev_sets()
    sentence = load_sentence_model()
    embeddings, info = load_embeddings("auto", params=Word2VecParams(),
                                       cache_dir=args.cache_dir or None, progress=True)
    candidates = {}
    for text_weight in NAME_TEXT_WEIGHTS:
        for spelling_weight in NAME_SPELLING_WEIGHTS:
            candidates[("sentence", text_weight, spelling_weight)] = PhraseRegionRecommender(
                sentence.embed_phrases, wordnet=wordnet, name_text_weight=text_weight,
                name_spelling_weight=spelling_weight)
    for text_weight in NAME_TEXT_WEIGHTS:
        candidates[("word2vec", text_weight, 0.0)] = RegionRecommender(
            embeddings.embed_words, wordnet=wordnet, hubness=True, name_text_weight=text_weight)
    results = []
    for key, recommender in candidates.items():
        ranker = recommender_ranker(recommender)
        per_set = {name: evaluate(ranker, buildings)["queries"] for name, buildings in sets.items()}
        pooled = summarize([r for rows in per_set.values() for r in rows])
        results.append({"method": key[0], "name_text_weight": key[1],
                        "name_spelling_weight": key[2], "pooled": pooled,
                        "sets": {name: summarize(rows) for name, rows in per_set.items()}})
        cells = "  ".join(f"{summarize(rows)['top1']:4.0%}/{summarize(rows)['top3']:4.0%}"
                          for rows in per_set.values())
        print(f"{key[0]:9s} name_text {key[1]:.1f} name_spelling {key[2]:.1f}: {cells}  pooled "
              f"top-1 {pooled['top1']:.1%} top-3 {pooled['top3']:.1%}", flush=True)
    chosen = {}
    for method in ("sentence", "word2vec"):
        ranked = sorted((r for r in results if r["method"] == method), key=lambda r: (
            -r["pooled"]["top1"], -r["pooled"]["top3"], r["name_spelling_weight"],
            r["name_text_weight"]))
        chosen[method] = ranked[0]
        print(f"chosen for {method}: name_text_weight {ranked[0]['name_text_weight']}, "
              f"name_spelling_weight {ranked[0]['name_spelling_weight']} (dev top-1 "
              f"{ranked[0]['pooled']['top1']:.1%})")
    path = write_json("nlp_region_accuracy_dev", {
        "sets": list(sets), "word2vec": info["corpora"], "results": results, "chosen": chosen})
    print(f"\nwrote {path}")
    return 0


def plot_shipped(table, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = list(table)
    fig, ax = plt.subplots(figsize=(9, 0.5 * len(keys) + 1.5))
    for offset, (metric, colour) in enumerate((("top1", "#3182bd"), ("top3", "#9ecae1"))):
        ys = [i + 0.2 - 0.4 * offset for i in range(len(keys))]
        values = [table[k][metric] for k in keys]
        low = [table[k][metric] - table[k][metric + "_ci95"][0] for k in keys]
        high = [table[k][metric + "_ci95"][1] - table[k][metric] for k in keys]
        ax.barh(ys, values, height=0.4, color=colour, xerr=[low, high], capsize=3,
                label=f"{metric[:3]}-{metric[3]} (95% Wilson CI)")
    ax.axvline(0.9, color="red", linestyle="--", linewidth=1, label="target top-1 90%")
    ax.set_yticks(list(range(len(keys))))
    ax.set_yticklabels([f"{c}\n{n} (n={table[(c, n)]['n']})" for c, n in keys], fontsize=6)
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel("accuracy on held-out test queries")
    ax.legend(loc="lower left", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def report(results, models) -> None:
    print(f"\n{'variant':56s} {'dev top1/top3':>14s} {'test top1/top3':>15s} {'all top1/top3':>14s}")
    for name, result in results.items():
        s = result["summary"]
        cells = [f"{s[k]['top1']:5.0%} /{s[k]['top3']:5.0%}" for k in ("dev", "test", "all")]
        mark = {PRODUCT: "  <- product default", FALLBACK: "  <- word2vec default (fallback)"}
        print(f"{name:56s} {cells[0]:>14s} {cells[1]:>15s} {cells[2]:>14s}{mark.get(name, '')}")
    print(f"\nmodels (machine load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores):")
    for source, model in models.items():
        fresh = model["fresh_process"]
        if source == "sentence":
            print(f"  sentence       {model['description']}; load in this process "
                  f"{model['in_process_load_seconds']:.1f} s")
        else:
            print(f"  {source:14s} word2vec (skip-gram) {model['words']:6d} words x "
                  f"{model['dimension']}, {model['tokens'] / 1e6:.2f} M tokens, trained in "
                  f"{model['train_seconds']:.1f} s")
        print(f"  {'':14s} fresh process, imports included, to the first vector: "
              f"{fresh['seconds']:.1f} s (loader {fresh['load_seconds']:.1f} s)")
    for name in (PRODUCT, FALLBACK):
        if name in results:
            print(f"\n{name} misses (all queries):")
            for row in results[name]["queries"]:
                if not row["top1_ok"]:
                    print(f"  [{row['split']}] {row['phrase']!r}: expected {row['expected']}, "
                          f"got {row['top3']}")


def plot(results, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(results)
    top1 = [results[n]["summary"]["all"]["top1"] for n in names]
    top3 = [results[n]["summary"]["all"]["top3"] for n in names]
    fig, ax = plt.subplots(figsize=(10, 0.32 * len(names) + 1.5))
    ys = range(len(names))
    ax.barh([y + 0.2 for y in ys], top3, height=0.4, label="top-3", color="#9ecae1")
    ax.barh([y - 0.2 for y in ys], top1, height=0.4, label="top-1", color="#3182bd")
    ax.axvline(0.8, color="red", linestyle="--", linewidth=1, label="target top-1 80%")
    ax.set_yticks(list(ys))
    ax.set_yticklabels(names, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel("accuracy over all queries")
    ax.legend(loc="lower right", fontsize=7)
    ax.set_title("Region recommender accuracy by variant")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    start = time.monotonic()
    status = main()
    print(f"({time.monotonic() - start:.0f} s)")
    sys.exit(status)
