"""The robot's data API: record ROS topics into CouchDB or MongoDB, replay them, convert bags."""
