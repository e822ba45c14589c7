"""Which people message the people counter uses for a scan (no roscore needed): the one nearest
the scan's stamp, waited for, since a tracker reports on a scan after the scan."""
from traffic_gp.ros_counter import nearest_people

# (stamp, people) as the counter keeps them; the people lists stand in for detections
MESSAGES = [(10.0, ["a"]), (10.1, ["b"])]


def test_a_scan_waits_for_its_own_message_rather_than_take_the_one_before():
    # the scan of 10.2 s came before its tracker message: the 10.1 s message is within the
    # timeout, but a nearer one may still come, so nothing yet
    assert nearest_people(MESSAGES, 10.2, 0.5) is None
    assert nearest_people(MESSAGES + [(10.2, ["c"])], 10.2, 0.5) == (10.2, ["c"])
    # no message came within the wait: the nearest one before it is used
    assert nearest_people(MESSAGES, 10.2, 0.5, final=True) == (10.1, ["b"])


def test_the_nearest_message_is_used_on_either_side_of_the_scan():
    messages = [(10.0, ["a"]), (10.3, ["d"])]         # a tracker slower than the laser
    assert nearest_people(messages, 10.1, 0.5) == (10.0, ["a"])
    assert nearest_people(messages, 10.2, 0.5) == (10.3, ["d"])


def test_a_message_beyond_the_timeout_is_not_used():
    assert nearest_people(MESSAGES, 10.7, 0.5, final=True) is None
    assert nearest_people([(11.0, ["e"])], 10.4, 0.5) is None
    assert nearest_people([], 10.0, 0.5, final=True) is None
