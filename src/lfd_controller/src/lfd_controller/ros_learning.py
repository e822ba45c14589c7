"""Learning from what the robot recorded: demonstrations from bags and the database (ros_mongo),
the learned reward back into the database; the learning itself is `learning.learn_and_save`.

Every failure to read or write a source is an LfdError (DemonstrationError when no usable
demonstration is found), which learn_reward turns into one `ERROR:` line.
"""
from typing import List, Optional, Sequence

import yaml
from std_msgs.msg import String

from lfd_controller import ros_demos
from lfd_controller.demos import Demonstration
from lfd_controller.errors import DemonstrationError, LfdError
from lfd_controller.learning import learn_and_save
from ros_mongo import StoreError, open_store


def load_sources(bags: Sequence[str], db_url: str = "", scenario: str = "",
                 session_id: str = "") -> List[Demonstration]:
    """Demonstrations from bag files/folders and the database (of one session, if given)."""
    demos = ros_demos.read_bags(bags) if bags else []
    if db_url:
        try:
            with open_store(db_url) as store:
                demos += ros_demos.load_demos(store, scenario=scenario or None,
                                              session_id=session_id or None)
        except StoreError as err:
            raise DemonstrationError(f"cannot load demonstrations from {db_url}: {err}") from err
    if scenario:
        demos = [d for d in demos if d.scenario.name == scenario]
    if not demos:
        where = f" for scenario {scenario!r}" if scenario else ""
        raise DemonstrationError(f"no demonstrations found{where}")
    return demos


def store_reward(reward, db_url: str, info: Optional[dict] = None) -> str:
    """Stores the reward (YAML in a std_msgs/String on /lfd/rewards); returns its database id."""
    try:
        with open_store(db_url) as store:
            text = yaml.safe_dump(dict(reward.to_dict(), info=info or {}), sort_keys=False)
            return store.insert_message(ros_demos.REWARD_TOPIC, String(data=text),
                                        tags=["reward", reward.kind])
    except StoreError as err:
        raise LfdError(f"cannot store the reward in {db_url}: {err}") from err


def learn_from_sources(bags, db_url: str = "", *, scenario: str = "", session_id: str = "",
                       kind: str = "linear", output: str, store_db: bool = False, plots: str = "",
                       seed: int = 0, trim_steps: Optional[int] = 10) -> str:
    """Load, learn, save (store with `store_db` and a `db_url`, and plot); returns a summary."""
    demos = load_sources(bags, db_url, scenario, session_id)

    def store(reward, info):
        return store_reward(reward, db_url, info)

    return learn_and_save(demos, kind=kind, output=output, plots=plots, seed=seed,
                          trim_steps=trim_steps, store=store if store_db and db_url else None)
