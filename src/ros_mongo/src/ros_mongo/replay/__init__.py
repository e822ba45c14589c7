"""Replay: stored messages republished in time (the replayer, its loader process) and the
ros_mongo_retriever node (ros_retriever)."""
