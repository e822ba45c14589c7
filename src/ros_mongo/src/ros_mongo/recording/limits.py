"""The spool's default limits and droppable types, written once for the spool and the recorder's
parameters (a module without imports: reading the parameters does not load the spool)."""

__all__ = ["DEFAULT_MAX_BYTES", "DEFAULT_MIN_FREE_BYTES", "DROPPABLE_TYPES"]

#: The spool's size limit on disk (bytes).
DEFAULT_MAX_BYTES = 4 << 30
#: Free disk space the spool leaves (bytes).
DEFAULT_MIN_FREE_BYTES = 1 << 30
#: The message types dropped oldest-first when the spool is full (unless configured otherwise).
DROPPABLE_TYPES = ("sensor_msgs/Image", "sensor_msgs/CompressedImage")
