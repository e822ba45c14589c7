"""`python -m ros_mongo.replay.loader`: the replay's loader process (see ros_mongo.replay.replay).

Reads (url, options, query) pickled from stdin; writes pickled chunks of messages to stdout.
"""
import os
import pickle
import sys

from ros_mongo.replay.replay import load

if __name__ == "__main__":
    os.nice(10)  # reading ahead must not take the processor from the player when it is scarce
    url, options, window = pickle.load(sys.stdin.buffer)
    load(url, options, window, sys.stdout.buffer)
