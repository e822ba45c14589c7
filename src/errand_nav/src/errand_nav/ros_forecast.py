"""The crowd forecast for a trip, from traffic_gp's ~predict_density (one call)."""
import math
from typing import Optional, Tuple

import numpy as np
import rospy

from errand_nav.forecast import DensityForecast
from errand_nav.params import ErrandServerParams
from traffic_gp.srv import PredictDensity, PredictDensityRequest

__all__ = ["ask_forecast"]


def ask_forecast(config: ErrandServerParams, departure: float,
                 trip: float) -> Tuple[Optional[DensityForecast], str]:
    """(forecast or None, a note for /diagnostics): the density grids at `departure` (s) and
    every ~forecast_step s over 1.5 x the `trip`'s expected seconds (at most ~forecast_horizon)."""
    horizon = min(config.forecast_horizon, 1.5 * trip + config.forecast_step)
    count = max(2, int(math.ceil(horizon / config.forecast_step)) + 1)
    stamps = [rospy.Time.from_sec(departure + k * config.forecast_step) for k in range(count)]
    try:
        rospy.wait_for_service(config.density_service, timeout=2.0)
        answer = rospy.ServiceProxy(config.density_service, PredictDensity)(
            PredictDensityRequest(stamps=stamps))
    except (rospy.ROSException, rospy.ServiceException) as err:
        return None, f"no crowd forecast ({err}): shortest travel time"
    if not answer.success:
        return None, f"no crowd forecast ({answer.message}): shortest travel time"
    info = answer.info
    grids = np.asarray(answer.density, float).reshape(len(stamps), info.height, info.width)
    note = f"traffic_gp forecast at {len(stamps)} times, {config.forecast_step:g} s apart"
    return DensityForecast((info.origin.position.x, info.origin.position.y), info.resolution,
                           np.array([s.to_sec() for s in stamps]), grids), note
