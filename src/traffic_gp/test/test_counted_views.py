"""The demo model's training counts (`traffic_gp.sim.counted`): what a robot's people counter
counts at stops, against the people simulator's truth (no ROS)."""
import numpy as np

from robot_common.cells import exposure
from traffic_gp.params import PeopleCounterParams
from traffic_gp.sim.counted import counted_views
from traffic_gp.sim.evaluation import simulator_for


def test_counted_stops_hold_about_the_simulated_people_where_the_laser_reached():
    sim = simulator_for("generated:0", 0.5, seed=1)
    views = counted_views(sim, 150, scans=5, seed=3)
    assert len(views) >= 140                      # a stop sees some cell unless in a wall's corner
    counted = truth = 0.0
    reach = PeopleCounterParams().max_range + sim.cells.cell_size
    for view in views:
        assert 0 <= view.t < 2 * 168 and view.duration > 0
        assert np.all(np.hypot(sim.cells.x[view.cells] - view.x,
                               sim.cells.y[view.cells] - view.y) <= reach)
        expected = sim.density(view.t, view.cells)[0] * exposure(
            view.fractions * sim.cells.cell_area, view.duration, sim.dwell_time)
        counted, truth = counted + view.counts.sum(), truth + expected.sum()
    # 10% misses and a track counted only after 3 detections in 5 scans: a little under the truth
    assert truth > 50 and 0.7 <= counted / truth <= 1.15, (counted, truth)
