"""Region search: phrases -> labelled places of the generated building (region_search nodes)."""
import time

import rospy

from robot_demo import waits
from robot_sim.building import generate_building

TITLE = "Where is ...? Phrases to labelled regions (embedding_server + region_recommender)"
PHRASES = ["drinking fountain", "somewhere to print a poster", "I need coffee",
           "a place to take a nap", "classroom 102", "wash my hands", "where are the microscopes",
           "meeting room", "a snack", "the printerz room", "the parking garage",
           "visit a patient"]  # the last two: places this building does not have


def run(demo) -> None:
    from region_search.srv import Embed, PhraseSimilarity, RecommendRegion

    labels = demo.output / "building_labels.json"  # written by the robot chapter's map_publisher
    if not labels.is_file():
        labels = demo.output / "region_search_labels.json"
        labels.write_text(generate_building(0).labels_json())
    print(f"  labels: {labels} ({labels.read_text().count('orientation')} places); embedding "
          "backend: the shipped default (pretrained sentence model all-MiniLM-L6-v2, CPU)")
    start = time.monotonic()
    launch = demo.launch("region_search", "region_search.launch", labels_path=str(labels))
    waits.services(launch, ["/embedding_server/embed", "/embedding_server/similarity",
                            "/region_recommender/recommend"], 300)
    # The services are advertised at once; the model is ready when ~active_backend is set (the
    # word2vec fallback trains for minutes on a machine that never trained it: the bound allows it).
    embed = rospy.ServiceProxy("/embedding_server/embed", Embed)
    waits.wait_until(lambda: rospy.has_param("/embedding_server/active_backend"), 900,
                     "the embedding model to be ready", interval=0.2)
    probe = embed(phrases=["robot"])
    print(f"  nodes ready in {time.monotonic() - start:.1f} s; backend {probe.backend}: "
          f"{probe.model}")
    if probe.backend_note:
        print(f"  NOTE: {probe.backend_note}")
    recommend = rospy.ServiceProxy("/region_recommender/recommend", RecommendRegion,
                                   persistent=True)
    begin = time.perf_counter()
    recommend(phrase="warm up", top_k=1)
    print(f"  first request (labels expanded with WordNet and encoded once): "
          f"{1000 * (time.perf_counter() - begin):.0f} ms")
    for phrase in PHRASES:
        begin = time.perf_counter()
        response = recommend(phrase=phrase, top_k=3)
        took = 1000 * (time.perf_counter() - begin)
        if not response.success:
            raise RuntimeError(f"{phrase!r}: {response.message}")
        ranked = ", ".join(f"{label} {score:.2f} ({pose.position.x:.1f}, {pose.position.y:.1f})"
                           for label, score, pose in zip(response.labels, response.scores,
                                                         response.poses))
        if not response.matched:
            ranked = response.message
        elif response.confidence == response.confidence:      # NaN: no calibration shipped
            unsure = ", not sure" if response.message.startswith("not sure") else ""
            ranked += f"  (confidence {response.confidence:.2f}{unsure})"
        print(f"  {phrase!r:30s} -> {ranked}   [{took:.1f} ms]")
        if response.fallbacks:
            print(f"  {'':30s}    out of vocabulary: {'; '.join(response.fallbacks)}")
    first = recommend(phrase=PHRASES[0], top_k=1)
    print(f"  why the first one won: {first.explanations[0] if first.matched else first.message}")
    empty = recommend(phrase="", top_k=3)
    print(f"  ''{'':28s} -> success={empty.success}: {empty.message}")
    similarity = rospy.ServiceProxy("/embedding_server/similarity", PhraseSimilarity)
    candidates = ["kitchen", "printer room", "water fountain", "elevator"]
    scored = similarity(phrase="I am thirsty", candidates=candidates, method="mean")
    print("  embedding_server ~similarity('I am thirsty'): "
          + ", ".join(f"{c} {s:.2f}" for c, s in zip(candidates, scored.scores)))
