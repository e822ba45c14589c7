#!/usr/bin/env python3
"""Latency of the embedding service and the region recommender through ROS (real roscore and
nodes), against the same calls in-process, and each backend's load time.

    python bench/region_search/nlp_service_latency.py [--quick] [--calls N]
        [--backends sentence,static,word2vec] [--source auto] [--brown PATH] [--cache-dir DIR]

Backends: "sentence" (the product default: all-MiniLM-L6-v2), "static" (the fallback without
PyTorch: WordLlama's static vectors) and "word2vec" (WordNet glosses unless --brown names a Brown
corpus, cached), each with the shipped ranking
(region_search.ranking, region_search/ranking_weights.yaml). Each service is
called over one persistent connection, as the recommender calls the embedding server, with the
evaluation set's phrases (data/region_eval.yaml) in turn, each in up to 42 wordings
("where is ...", "... please"), so that no query is repeated and every query runs the model (the
servers run with their shipped settings, phrase cache on: a repeated query would be a cache hit);
labels and candidates repeat, as in use. In-process figures also give the CPU time per call (the
latency a quiet machine would see; wall times are noisy when the 2 cores are shared).
Target: RecommendRegion p50 <= 30 ms through ROS with the other nodes running (the peer: the
same ranking in-process, as a ratio). Load time: the backend's loader in a fresh process
(imports included, to the first vector) and the nodes' start-up (roslaunch to services
registered, which is at once, and to the model ready: ~active_backend set and the first
recommendation answered).
Writes artifacts/bench/nlp_service_latency.json and nlp_service_latency.png.
"""
import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import rospy
import yaml
from nlp_common import OUT_DIR, ROOT, fresh_process_load_seconds, load_eval, percentile, write_json

from region_search.backends import EmbeddingServerParams, load_backend
from region_search.corpora import WordNet
from region_search.labels import Region
from region_search.ranking import PlaceRecommender, SentenceFeatures, WordFeatures, load_ranking_weights
from region_search.srv import Embed, PhraseSimilarity, RecommendRegion
from ros_harness import RosCore, RosLaunch, wait_until

CONFIG = ROOT / "src" / "region_search" / "config"
PREFIXES = ["", "where is ", "please find ", "I am looking for ", "take me to ", "show me ",
            "can you find "]
SUFFIXES = ["", " please", " now", " quickly", " on this floor", " for me"]
SERVICES = {"embed": "Embed (1 phrase)", "similarity": "PhraseSimilarity (1 vs {n} candidates)",
            "recommend": "RecommendRegion ({n} labels, top 3)"}


def query_phrases(base, service: int, calls: int):
    """`calls` distinct queries: the base phrases in turn, worded differently in each round;
    each service (0, 1, 2) gets its own wordings, so no service sees another's queries."""
    wordings = [(prefix, suffix) for suffix in SUFFIXES for prefix in PREFIXES]
    phrases = []
    for index in range(calls):
        round_, which = divmod(index, len(base))
        prefix, suffix = wordings[(round_ * len(SERVICES) + service) % len(wordings)]
        phrases.append(prefix + base[which] + suffix)
    return phrases


def timed(call, phrases):
    """{p50_ms, p99_ms, max_ms, cpu_p50_ms, cpu_p99_ms} of call(phrase) for each phrase."""
    times, cpu = [], []
    for index, phrase in enumerate(phrases):
        start, start_cpu = time.perf_counter(), time.thread_time()
        result = call(phrase)
        cpu.append(1000.0 * (time.thread_time() - start_cpu))
        times.append(1000.0 * (time.perf_counter() - start))
        if getattr(result, "success", True) is False:
            raise RuntimeError(f"call {index} failed: {result.message}")
    return {"calls": len(times), "p50_ms": percentile(times, 50), "p99_ms": percentile(times, 99),
            "max_ms": max(times), "cpu_p50_ms": percentile(cpu, 50), "cpu_p99_ms": percentile(cpu, 99)}


def server_params(backend: str, args) -> dict:
    params = yaml.safe_load((CONFIG / "embeddings.yaml").read_text())
    params.update(backend=backend, source=args.source, brown_path=args.brown,
                  cache_dir=args.cache_dir)
    return params


def in_process(backend: str, args, phrases, labels, calls) -> dict:
    """The same calls without ROS (the peer): model, recommender and calls in this process."""
    loaded = load_backend(EmbeddingServerParams(backend=backend, source=args.source,
                                        brown_path=args.brown, cache_dir=args.cache_dir))
    embeddings = loaded.embeddings
    embeddings.warm_up()
    if embeddings.phrase_level:  # sentence, static
        local = PlaceRecommender(SentenceFeatures(embeddings.embed_phrases, WordNet()),
                                 load_ranking_weights(loaded.backend))
    else:
        local = PlaceRecommender(WordFeatures(embeddings.embed_words, WordNet()),
                                 load_ranking_weights("word2vec"))
    local.set_regions([Region(name, float(i), 1.0) for i, name in enumerate(labels)])
    return {"model": embeddings.description, "timings": {
        "embed": timed(lambda p: embeddings.embed_phrases([p]), query_phrases(phrases, 0, calls)),
        "similarity": timed(lambda p: embeddings.similarity(p, labels, "mean"),
                            query_phrases(phrases, 1, calls)),
        "recommend": timed(lambda p: local.recommend(p, 3), query_phrases(phrases, 2, calls))}}


def through_ros(backend: str, args, core, work: Path, phrases, labels, calls) -> dict:
    env, logs = core.env(), work / "logs"
    started = time.monotonic()
    server = RosLaunch.node("region_search", "embedding_server", name="embedding_server",
                            master_uri=core.uri, log_dir=logs, env=env,
                            params=server_params(backend, args)).start()
    recommender_params = yaml.safe_load((CONFIG / "region_search.yaml").read_text())
    recommender_params.update(labels_path=str(work / "labels.json"), layer_service="")
    recommender = RosLaunch.node("region_search", "region_recommender", name="region_recommender",
                                 master_uri=core.uri, log_dir=logs, env=env,
                                 params=recommender_params).start()
    try:
        server.wait_for_services(["/embedding_server/embed"], timeout=120)
        services_up = time.monotonic() - started
        wait_until(lambda: rospy.has_param("/embedding_server/active_backend"), 3600,
                   interval=0.2, what="the embedding model ready")
        server_up = time.monotonic() - started
        recommender.wait_for_services(["/region_recommender/recommend"], timeout=120)
        embed = rospy.ServiceProxy("/embedding_server/embed", Embed, persistent=True)
        similarity = rospy.ServiceProxy("/embedding_server/similarity", PhraseSimilarity,
                                        persistent=True)
        recommend = rospy.ServiceProxy("/region_recommender/recommend", RecommendRegion,
                                       persistent=True)
        # labels expanded and encoded on the first successful call
        first = wait_until(lambda: (lambda r: r if r.success else None)(
            recommend(phrase="warm up", top_k=3)), 120, what="the first recommendation")
        nodes_up = time.monotonic() - started
        timings = {
            "embed": timed(lambda p: embed(phrases=[p]), query_phrases(phrases, 0, calls)),
            "similarity": timed(lambda p: similarity(phrase=p, candidates=labels, method="mean"),
                                query_phrases(phrases, 1, calls)),
            "recommend": timed(lambda p: recommend(phrase=p, top_k=3),
                               query_phrases(phrases, 2, calls))}
        for proxy in (embed, similarity, recommend):
            proxy.close()
    finally:
        recommender.stop()
        server.stop()
    return {"backend": first.backend, "backend_note": first.backend_note,
            "services_up_seconds": services_up, "server_up_seconds": server_up,
            "nodes_up_seconds": nodes_up, "timings": timings}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="100 calls per service")
    parser.add_argument("--calls", type=int, default=1000)
    parser.add_argument("--backends", default="sentence,static,word2vec",
                        help="comma-separated; the first is the one the target applies to")
    parser.add_argument("--source", default="auto", help="word2vec model (auto: Brown + glosses)")
    parser.add_argument("--brown", default="", help="a Brown corpus for word2vec ('' = only where "
                        "NLTK looks, as on a robot)")
    parser.add_argument("--cache-dir", default="", help="word2vec model cache ('' = default)")
    args = parser.parse_args()
    args.brown = args.brown if args.brown and Path(args.brown).exists() else ""
    calls = 100 if args.quick else args.calls
    backends = [b.strip() for b in args.backends.split(",") if b.strip()]
    evaluation = load_eval()
    labels = evaluation["levine_towne"]["labels"]
    phrases = [q["phrase"] for b in evaluation.values() for q in b["queries"]]
    work = Path(tempfile.mkdtemp(prefix="nlp_latency_"))
    (work / "labels.json").write_text(json.dumps(
        {name: {"x": float(i), "y": 1.0, "orientation": [0, 0, 0, 1]} for i, name in enumerate(labels)}))

    results = {}
    for backend in backends:
        print(f"{backend}: loading in a fresh process ...", flush=True)
        load = fresh_process_load_seconds(backend=backend, source=args.source, brown_path=args.brown,
                                          cache_dir=args.cache_dir)
        print(f"{backend}: in-process calls ...", flush=True)
        results[backend] = {"fresh_process_load": load,
                            "in_process": in_process(backend, args, phrases, labels, calls)}
    core = RosCore(log_dir=work / "logs").start()
    os.environ.update(core.env())
    try:
        rospy.init_node("nlp_latency_bench", anonymous=True, disable_signals=True)
        for backend in backends:
            print(f"{backend}: through ROS ...", flush=True)
            results[backend]["ros"] = through_ros(backend, args, core, work, phrases, labels, calls)
        rospy.signal_shutdown("bench finished")
    finally:
        core.stop()
    report(results, backends, len(labels), calls)
    path = write_json("nlp_service_latency", {
        "calls": calls, "candidates": len(labels), "phrases": len(phrases), "results": results,
        "default_backend": backends[0], "load_average": os.getloadavg()})
    plot(results, backends, len(labels))
    print(f"\nwrote {path} and {OUT_DIR / 'nlp_service_latency.png'}")
    return 0


def report(results, backends, candidates, calls) -> None:
    print(f"\nmachine load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; "
          f"{calls} calls per service, distinct phrases (evaluation set, reworded)")
    for backend in backends:
        result, ros = results[backend], results[backend]["ros"]
        note = f" [{ros['backend_note']}]" if ros["backend_note"] else ""
        print(f"\n{backend}: {result['in_process']['model']}{note}")
        print(f"  load, fresh process to the first vector (imports included): "
              f"{result['fresh_process_load']['seconds']:.1f} s; roslaunch to: services "
              f"advertised {ros['services_up_seconds']:.1f} s, model ready "
              f"{ros['server_up_seconds']:.1f} s, first recommendation "
              f"{ros['nodes_up_seconds']:.1f} s")
        print(f"  {'service':40s} {'ROS p50':>8s} {'ROS p99':>8s} {'local p50':>10s} "
              f"{'local p99':>10s} {'p50 ratio':>10s} {'local CPU p50/p99':>18s}")
        for key, name in SERVICES.items():
            r, p = ros["timings"][key], result["in_process"]["timings"][key]
            print(f"  {name.format(n=candidates):40s} {r['p50_ms']:7.2f}ms {r['p99_ms']:7.2f}ms "
                  f"{p['p50_ms']:9.2f}ms {p['p99_ms']:9.2f}ms "
                  f"{r['p50_ms'] / max(p['p50_ms'], 1e-6):9.1f}x "
                  f"{p['cpu_p50_ms']:7.2f} /{p['cpu_p99_ms']:6.2f} ms")
    default = results[backends[0]]["ros"]["timings"]
    p50 = default["recommend"]["p50_ms"]
    print(f"\ntarget RecommendRegion p50 <= 30 ms ({backends[0]} backend, through ROS): "
          f"{'met' if p50 <= 30 else 'NOT met'} (p50 {p50:.1f} ms, p99 "
          f"{default['recommend']['p99_ms']:.1f} ms)")
    if len(backends) > 1:
        other = results[backends[1]]["ros"]["timings"]["recommend"]["p50_ms"]
        print(f"RecommendRegion p50 {backends[0]} / {backends[1]}: "
              f"{default['recommend']['p50_ms'] / max(other, 1e-6):.1f}x")


def plot(results, backends, candidates) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(backends), figsize=(5.5 * len(backends), 3.8), squeeze=False)
    for ax, backend in zip(axes[0], backends):
        timings = results[backend]["ros"]["timings"]
        for offset, key in enumerate(("p50_ms", "p99_ms")):
            ax.bar([i + 0.4 * offset for i in range(len(SERVICES))],
                   [timings[name][key] for name in SERVICES], width=0.4, label=key[:3])
        ax.axhline(30, color="red", linestyle="--", linewidth=1, label="target p50 30 ms")
        ax.set_xticks([i + 0.2 for i in range(len(SERVICES))])
        ax.set_xticklabels([n.format(n=candidates) for n in SERVICES.values()], fontsize=6)
        ax.set_ylabel("ms (ROS round trip)")
        ax.set_title(f"{backend} backend", fontsize=9)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(OUT_DIR / "nlp_service_latency.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
