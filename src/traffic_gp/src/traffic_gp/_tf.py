"""The one place that imports TensorFlow and GPflow: threads, float64 and the optimiser shim.

Nothing is imported until `libs()` is first called, so every other module of the package can be
imported without TensorFlow.

TensorFlow >= 2.16 ships Keras 3, whose optimisers cannot minimise GPflow's variables; GPflow
then needs the `tf_keras` package and exposes it as `gpflow.keras.tf_keras` (GPflow >= 2.9.1;
on our Python 3.8 pin set, TF 2.13 + GPflow 2.9.2, that name is plain `tf.keras`, whose Adam
has `minimize` too). Older GPflow has no `gpflow.keras`: then `tf.keras` is the right one.
"""
import os
import sys
from types import SimpleNamespace

import numpy as np

_LIBS = {}


def libs() -> SimpleNamespace:
    """tensorflow (`tf`), `gpflow`, and `Adam` (a Keras-2 optimiser class), imported once;
    GPflow's default float is then float64.

    Threads: `TRAFFIC_GP_TF_THREADS` (else TensorFlow's own `TF_NUM_INTRAOP_THREADS`, else up to
    2, the cores of our robots' computers) for work inside one operation, one thread between
    operations.
    """
    if not _LIBS:
        os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")
        # tf.keras as tf_keras (Keras 2, what GPflow's optimiser comes from anyway): TensorFlow
        # then does not import Keras 3 (with pandas and matplotlib), about a CPU-second per process
        os.environ.setdefault("TF_USE_LEGACY_KERAS", "1")
        import tensorflow as tf

        threads = int(os.environ.get("TRAFFIC_GP_TF_THREADS")
                      or os.environ.get("TF_NUM_INTRAOP_THREADS") or min(2, os.cpu_count() or 1))
        try:
            tf.config.threading.set_intra_op_parallelism_threads(threads)
            tf.config.threading.set_inter_op_parallelism_threads(1)
        except RuntimeError:  # TensorFlow was already running in this process: keep its threads
            pass
        gpflow = _import_gpflow()
        gpflow.config.set_default_float(np.float64)
        try:
            from gpflow.keras import tf_keras
        except ImportError:  # GPflow < 2.9.1 (with TensorFlow < 2.16)
            tf_keras = tf.keras
        _LIBS.update(tf=tf, gpflow=gpflow, Adam=tf_keras.optimizers.Adam,
                     versions=f"tensorflow {tf.__version__}, gpflow {gpflow.__version__}")
    return SimpleNamespace(**_LIBS)


def _import_gpflow():
    """gpflow, without PyTorch: its `check_shapes` imports PyTorch when installed, only to accept
    torch tensors (none ever reach it here), for seconds of CPU in every process that trains.
    A process that already has PyTorch keeps it; later imports of it are not affected."""
    blocked = "torch" not in sys.modules
    if blocked:
        sys.modules["torch"] = None  # `import torch` raises ImportError meanwhile
    try:
        import gpflow
    finally:
        if blocked and "torch" in sys.modules and sys.modules["torch"] is None:
            del sys.modules["torch"]
    return gpflow
