"""Recording: the recorder core (queue, ordered batched writes), its records, the chunking of
high-rate topics, the bounded spool, quarantine, and the ros_mongo_server node (ros_recorder)."""
