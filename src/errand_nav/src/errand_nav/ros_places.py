"""PlaceGoals: errand_server's ~go_to_place (a phrase -> region_search -> a goal, when sure)."""
import math
from typing import Callable

import rospy
from geometry_msgs.msg import PoseStamped

from errand_nav.params import ErrandServerParams
from errand_nav.places import PlaceChoice, choose_place
from errand_nav.srv import GoToPlace, GoToPlaceResponse
from region_search.srv import RecommendRegion, RecommendRegionRequest
from robot_common.maps import quaternion_to_yaw, yaw_to_quaternion

__all__ = ["PlaceGoals"]


class PlaceGoals:
    """~go_to_place (errand_nav/GoToPlace): asks ~recommend_service (region_search's
    RecommendRegion) which place the phrase means; when region_search is sure (and its
    confidence is at least ~min_confidence), sends the place's pose to `send_goal` (the node's
    own move_base action); otherwise answers "not sure" with the candidates and sends nothing."""

    def __init__(self, config: ErrandServerParams, send_goal: Callable[[PoseStamped], None]):
        self.config, self.send_goal = config, send_goal
        self.frame = config.map_frame

    def setup(self) -> "PlaceGoals":
        rospy.Service("~go_to_place", GoToPlace, self.on_go_to_place)
        return self

    def ask(self, phrase: str) -> PlaceChoice:
        try:
            rospy.wait_for_service(self.config.recommend_service, timeout=5.0)
            answer = rospy.ServiceProxy(self.config.recommend_service, RecommendRegion)(
                RecommendRegionRequest(phrase=phrase, top_k=self.config.candidates))
        except (rospy.ROSException, rospy.ServiceException) as err:
            return PlaceChoice(False, f"region_search is not reachable on "
                                      f"{self.config.recommend_service}: {err}")
        poses = [(p.position.x, p.position.y, quaternion_to_yaw(
            p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w))
            for p in answer.poses]
        choice = choose_place(phrase, success=answer.success, message=answer.message,
                              matched=answer.matched, labels=answer.labels,
                              scores=answer.scores, poses=poses,
                              confidence=float(answer.confidence),
                              min_confidence=self.config.min_confidence)
        self.frame = answer.frame_id or self.config.map_frame
        return choice

    def on_go_to_place(self, request) -> GoToPlaceResponse:
        phrase = request.phrase.strip()
        if not phrase:
            return GoToPlaceResponse(success=False, message="empty phrase", confidence=math.nan)
        choice = self.ask(phrase)
        response = GoToPlaceResponse(success=choice.sure, message=choice.message,
                                     label=choice.label, confidence=choice.confidence,
                                     candidates=choice.candidates, scores=choice.scores)
        if choice.label:
            goal = response.goal
            goal.header.frame_id, goal.header.stamp = self.frame, rospy.Time.now()
            goal.pose.position.x, goal.pose.position.y = choice.pose[:2]
            (goal.pose.orientation.x, goal.pose.orientation.y, goal.pose.orientation.z,
             goal.pose.orientation.w) = yaw_to_quaternion(choice.pose[2])
        rospy.loginfo(f"errand_server: ~go_to_place {phrase!r}: {choice.message}")
        if choice.sure and not request.dry_run:
            self.send_goal(response.goal)
        return response
