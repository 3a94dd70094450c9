"""rclpy's ActionClient with the race of rclpy#1123 closed, and feedback before the result.

A request sent from one thread can be answered, and its response taken and executed by the
executor on another thread, before send_goal_async (or the cancel and result requests) has
registered the request's future. rclpy then logs "Ignoring unexpected goal response" and the
future never completes: the caller waits out its timeout while the arm may be executing the
goal. Fixed upstream by a lock (rclpy#1308, backported in #1519), not yet in the Jazzy wheels
on PyPI. This subclass does the same: one re-entrant lock spans sending a request together
with registering its future, and executing whatever the executor took. Use it wherever an
ActionClient is created.

rclpy executes what one take brought in the order goal, cancel, result, feedback, status: a
feedback message the server published just before the result (as skill_node does after its
last placement) reached its callback only after the result's future was done, so a caller
woken by the result could miss it. Here that feedback goes to its callback first. Feedback and
result travel on different channels, so the result can still arrive first, in a take of its
own: a caller that needs every feedback waits for the count it expects (skill_trials does).
"""

from __future__ import annotations

import threading

from rclpy.action import ActionClient as _RclpyActionClient


class ActionClient(_RclpyActionClient):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        # re-entrant: a done callback run inside execute may send the next request
        self._requests = threading.RLock()

    def send_goal_async(self, *args, **kwargs):
        with self._requests:
            return super().send_goal_async(*args, **kwargs)

    def _cancel_goal_async(self, goal_handle):
        with self._requests:
            return super()._cancel_goal_async(goal_handle)

    def _get_result_async(self, goal_handle):
        with self._requests:
            return super()._get_result_async(goal_handle)

    async def execute(self, taken_data):
        with self._requests:
            if "feedback" in taken_data and "result" in taken_data:
                await super().execute({"feedback": taken_data["feedback"]})
                taken_data = {k: v for k, v in taken_data.items() if k != "feedback"}
            return await super().execute(taken_data)
