"""Fleet: robot -> central push replication, the changes follower of the central database,
local retention, the local database server command and the ros_mongo_replicator node."""
