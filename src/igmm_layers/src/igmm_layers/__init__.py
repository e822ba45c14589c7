"""Object layers: incremental Gaussian mixtures of object detections per class and map region."""
