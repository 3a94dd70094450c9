"""rclpy's MultiThreadedExecutor without two ways its spinning thread loops while it waits,
with a cheaper wait loop, and with quick done-callbacks run where their future completes.

While the spinning thread loops it holds the GIL, which the worker it is waiting for needs to
start. In bench_arm's graph (one process) a result reached its client 100-600 ms after its
goal ended in about one goal of three, and a pick-and-place took 0.6-0.9 s where 0.27 s does.

1. A subscription's QoS event handlers (rclpy gives each subscription two: incompatible QoS
   and incompatible type) wait on the subscription's DDS reader. Once a message has arrived
   and its callback is queued, the subscription leaves the wait set until a worker takes the
   message, but its event handlers stay in it, and the reader's pending message ends every
   wait at once with no event ready: a busy loop. Here the event handlers leave with it.
2. rclpy#1452: `wait_for_ready_callbacks` hands out every task that is neither done nor
   executing, and this executor only queues for its pool what it is handed: until a worker
   starts a task, the task is handed out and queued again in every round of the wait loop (in
   the busy loop of 1., up to 700 times). Fixed in rclpy 10.0.4 (rolling, rclpy#1547), not in
   the Jazzy wheels on PyPI. Here a task counts as executing from the moment it is queued; the
   worker clears the mark just before it runs the task.

The wait loop hands out what rclpy's does, in the same order (test_executor.py holds it to
rclpy's own on the same pending work), at less cost per round. In the loop bench's graph (about
130 rounds and 130 callbacks per experiment) rclpy's loop cost the spinning thread about 1 ms
per round. Entities that serve tools rather than the graph's own traffic join the wait set every
POLL_S instead of every round, the wait cut short for the next poll (`polled`): the QoS event
handlers that report an incompatible QoS or type (two per publisher and subscription) and every
node's parameter and type-description services (seven per node: 56 of the ~110 entities a round
of the loop's graph would otherwise hold). A misconfigured peer is reported, and a `ros2 param`
or parameter client's request answered, at most POLL_S later.

A future's done-callbacks are executor tasks in rclpy (the executor that completed the future
queues them): a thread waiting for an answer is woken only after one more round of the wait
loop and a worker. `runs_inline(callback)` marks a callback that only wakes a waiting thread
(sets an Event); this executor runs such a callback at once, in the thread that completed the
future. So it does with rclpy's own quick done-callbacks: an action server's sending of a
result (a goal's result reached its client about 9 ms after the goal ended, now about 5 ms),
and the clients' forgetting of an answered request. Every other callback, and every callback
on another executor, runs as before.

Use it wherever a multi-threaded executor is made. `BackgroundSpin` spins an executor in a
thread of its own, for a graph that the calling thread only waits on (in-process graphs, tests).
"""

from __future__ import annotations

import functools
import threading
import time
import weakref
from collections.abc import Callable, Generator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from rclpy.action.client import ActionClient
from rclpy.action.server import ActionServer
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.client import Client
from rclpy.event_handler import EventHandler, QoSPublisherEventType, QoSSubscriptionEventType
from rclpy.exceptions import InvalidHandle
from rclpy.executors import (
    ConditionReachedException,
    Executor,
    ExternalShutdownException,
    ShutdownException,
    TimeoutException,
    TimeoutObject,
)
from rclpy.executors import MultiThreadedExecutor as _RclpyMultiThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.parameter_service import ParameterService
from rclpy.task import Future, Task
from rclpy.type_description_service import TypeDescriptionService
from rclpy.utilities import timeout_sec_to_nsec

_INLINE = "_katana_runs_inline"

#: how often the entities that serve tools (`polled`) join the wait set
POLL_S = 0.1

# (enum type, value): pybind's event enums compare equal across the two types by value
_SUB, _PUB = QoSSubscriptionEventType, QoSPublisherEventType
_INCOMPATIBILITY_EVENTS = {
    (_SUB, int(_SUB.RCL_SUBSCRIPTION_REQUESTED_INCOMPATIBLE_QOS)),
    (_SUB, int(_SUB.RCL_SUBSCRIPTION_INCOMPATIBLE_TYPE)),
    (_PUB, int(_PUB.RCL_PUBLISHER_OFFERED_INCOMPATIBLE_QOS)),
    (_PUB, int(_PUB.RCL_PUBLISHER_INCOMPATIBLE_TYPE)),
}


def reports_incompatibility(waitable: Any) -> bool:
    """Whether `waitable` is a QoS event handler for an incompatible QoS or type: rclpy gives
    every publisher and subscription these, and they report a misconfigured peer."""
    return isinstance(waitable, EventHandler) and (
        type(waitable.event_type), int(waitable.event_type)) in _INCOMPATIBILITY_EVENTS


def serves_tools(service: Any) -> bool:
    """Whether `service` is one rclpy gives every node for tools: its parameter services
    (`ros2 param`, parameter clients) and its type-description service."""
    owner = getattr(getattr(service, "callback", None), "__self__", None)
    return isinstance(owner, (ParameterService, TypeDescriptionService))


def polled(entity: Any) -> bool:
    """Whether `entity` joins the executor's wait set only every POLL_S: a QoS event handler
    that reports an incompatible peer, or a service that serves tools."""
    return reports_incompatibility(entity) or serves_tools(entity)


def runs_inline(callback: Callable) -> Callable:
    """Mark `callback` (quick, thread-safe, never raising: it sets an Event) to be run at once
    by this module's executor when a future completes, instead of as a task."""
    setattr(callback, _INLINE, True)
    return callback


# Done-callbacks rclpy adds itself that only hand a response to the middleware or forget a
# finished request (a dict entry under the client's lock, or in the action client's own
# bookkeeping): quick, and as thread-safe as in the worker rclpy would run them in. Run in the
# completing thread, they spare the spinning thread a round and a worker each (4 per goal). A
# name rclpy no longer has matches nothing, and the callback is a task again.
_QUICK_DONE_CALLBACKS = tuple(f for f in (
    getattr(ActionServer, "_send_result_response", None),  # via functools.partial
    getattr(ActionClient, "_remove_pending_goal_request", None),
    getattr(ActionClient, "_remove_pending_result_request", None),
    getattr(ActionClient, "_remove_pending_cancel_request", None),
    getattr(Client, "remove_pending_request", None),
) if f is not None)


def _runs_inline(callback: Callable) -> bool:
    if getattr(callback, _INLINE, False):
        return True
    if isinstance(callback, functools.partial):
        callback = callback.func
    return getattr(callback, "__func__", None) in _QUICK_DONE_CALLBACKS


#: the longest `MultiThreadedExecutor.shutdown()` waits for running callbacks when not told
DRAIN_TIMEOUT_S = 5.0


def _start(task: Task) -> None:
    task._executing = False  # rclpy's Task runs only when it is not marked executing
    task()


class _QueuedCountsAsExecuting:
    """The executor's thread pool; what it queues reports executing until a worker takes it."""

    def __init__(self, pool: ThreadPoolExecutor) -> None:
        self._pool = pool

    def submit(self, task: Task) -> Any:
        task._executing = True
        return self._pool.submit(_start, task)

    def __getattr__(self, name: str) -> Any:  # shutdown and the rest: the pool's own
        return getattr(self._pool, name)


class MultiThreadedExecutor(_RclpyMultiThreadedExecutor):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._executor = _QueuedCountsAsExecuting(self._executor)
        # event handler -> its subscription (None: a publisher's); only the spinning thread uses it
        self._subscription_of: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        # node -> its _Entities; only the spinning thread uses it
        self._entities_of: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        self._next_poll_ns = 0

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        """Stop executing callbacks and wait for the running ones to end, as rclpy documents
        it, at most `timeout_sec` (None or negative: DRAIN_TIMEOUT_S, so that a callback that
        never returns cannot hang the caller); whether they all ended. rclpy 7.1.5 sets
        `_is_shutdown` and then tests it to decide whether to wait, so it never waits, and
        callbacks queued for a worker still started afterwards: a node destroyed after it
        returned made such a callback raise InvalidHandle ("The following exception was never
        retrieved" at exit). Here a queued one ends at once when a worker takes it (the
        handler looks at the shutdown flag) and the running ones are waited for."""
        done = super().shutdown(timeout_sec)
        wait_s = DRAIN_TIMEOUT_S if timeout_sec is None or timeout_sec < 0 else timeout_sec
        return self._work_tracker.wait(wait_s) and done

    def create_task(self, callback: Callable, *args: Any, **kwargs: Any) -> Task | Future:
        """A callback marked `runs_inline`, or one of rclpy's quick done-callbacks, runs now
        (the returned future is done); any other becomes a task, as in rclpy."""
        if _runs_inline(callback):
            callback(*args, **kwargs)
            done: Future = Future()
            done.set_result(None)
            return done
        return super().create_task(callback, *args, **kwargs)

    def _make_handler(self, entity: Any, node: Any, take_from_wait_list: Callable) -> Task:
        """rclpy's handler (`Executor._make_handler`, rclpy 7.1.5), its wake of the spinning
        thread after the take guarded as its last one is: `shutdown()` destroys the guard
        condition without waiting for running callbacks, and a callback started just before
        raised InvalidHandle there (printed at exit as "The following exception was never
        retrieved"), leaving its callback group marked busy. A task that a worker takes after
        `shutdown()` ends without taking its message."""
        entity._executor_event = True  # out of the wait set until taken

        async def handler(entity, gc, is_shutdown, work_tracker):
            # counted as work before it looks at the shutdown flag: shutdown() sets the flag,
            # then waits for the work to end, so a callback either runs before it returns or
            # not at all (the `is_shutdown` rclpy passes is the flag when the task was made)
            with work_tracker:
                if (self._is_shutdown
                        or not entity.callback_group.beginning_execution(entity)):
                    entity._executor_event = False  # not run (busy group, or stopping)
                    _wake(gc)
                    return
                call_coroutine = take_from_wait_list(entity)
                entity._executor_event = False  # may join the wait set again
                _wake(gc)
                try:
                    if call_coroutine is not None:
                        await call_coroutine()
                finally:
                    entity.callback_group.ending_execution(entity)
                    _wake(gc)  # the next callback of its group may run

        task = Task(handler, (entity, self._guard, self._is_shutdown, self._work_tracker),
                    executor=self)
        with self._tasks_lock:
            self._tasks.append((task, entity, node))
        return task

    def can_execute(self, entity: Any) -> bool:
        if not super().can_execute(entity):
            return False
        if not isinstance(entity, EventHandler):
            return True
        if entity not in self._subscription_of:  # a handler not seen yet: map them all again
            for node in self.get_nodes():
                for subscription in node.subscriptions:
                    for handler in subscription.event_handlers:
                        self._subscription_of[handler] = weakref.ref(subscription)
            self._subscription_of.setdefault(entity, None)
        owner = self._subscription_of[entity]
        subscription = owner() if owner is not None else None
        return subscription is None or not subscription._executor_event

    def _wait_for_ready_callbacks(
        self,
        timeout_sec: float | TimeoutObject | None = None,
        nodes: list | None = None,
        condition: Callable[[], bool] = lambda: False,
    ) -> Generator[tuple[Task, Any, Any], None, None]:
        """rclpy's wait loop (`Executor._wait_for_ready_callbacks`, rclpy 7.1.5): the same work
        handed out in the same order, with the same exceptions, at a fraction of its cost per
        round. In a graph of a few hundred entities rclpy spends about 1 ms per round in
        Python, most of it in a membership test of every waitable against the list of all of
        them (quadratic), an ExitStack entry per entity and a new rcl timer per call for the
        timeout. Here: each node's entities with their handles, pointers and counts kept until
        its lists change (`_Entities`), a callback group asked once per round, sets for the
        ready entities, handles entered and left directly, and the timeout as a deadline
        passed to the wait."""
        if isinstance(timeout_sec, TimeoutObject):
            timeout_sec = timeout_sec.timeout
        timeout_ns = timeout_sec_to_nsec(timeout_sec)  # < 0: wait for ever; 0: do not wait
        deadline_ns = time.monotonic_ns() + timeout_ns if timeout_ns > 0 else None
        yielded_work = False
        while not yielded_work and not self._is_shutdown and not condition():
            nodes_to_use = self.get_nodes() if nodes is None else nodes

            # tasks in progress first, as rclpy does
            with self._tasks_lock:
                tasks = list(self._tasks)
            if tasks:
                for task, entity, node in reversed(tasks):
                    if (not task.executing() and not task.done()
                            and (node is None or node in nodes_to_use)):
                        yielded_work = True
                        yield task, entity, node
                with self._tasks_lock:
                    self._tasks = [t for t in self._tasks
                                   if not t[0].done() and not t[0].cancelled()]

            now_ns = time.monotonic_ns()
            poll = now_ns >= self._next_poll_ns
            if poll:
                self._next_poll_ns = now_ns + int(POLL_S * 1e9)
            allowed = _GroupVerdicts()
            of_node = [self._entities(node) for node in nodes_to_use]
            subscriptions, timers, clients, services, waitables = [], [], [], [], []
            guards = []
            for entities in of_node:
                subscriptions += [e for e in entities.subscriptions if allowed(e[0])]
                timers += [e for e in entities.timers if allowed(e[0])]
                clients += [e for e in entities.clients if allowed(e[0])]
                services += [e for e in (entities.services if poll
                                         else entities.unpolled_services) if allowed(e[0])]
                for entry in entities.guards:
                    gc = entry[0]
                    if allowed(gc):
                        if gc._executor_triggered:  # triggered but not handled: again
                            gc.trigger()
                        guards.append(entry)
                waitables += [e for e in (entities.waitables if poll
                                          else entities.unpolled_waitables)
                              if self.can_execute(e[0])]
            guards += [_entry(gc) for gc in (self._guard, self._sigint_gc)]

            entered: list = []  # handles in use while the wait set holds them
            try:
                subscriptions = _enter(subscriptions, entered)
                clients = _enter(clients, entered)
                services = _enter(services, entered)
                timers = _enter(timers, entered)
                guards = _enter(guards, entered)
                waitables = _enter(waitables, entered)  # a waitable is its own handle
                counts = [len(subscriptions), len(guards), len(timers), len(clients),
                          len(services), 0]
                for entry in waitables:
                    counts = [a + b for a, b in zip(counts, entry[2], strict=True)]
                self._context.handle.__enter__()
                entered.append(self._context.handle)
                wait_set = _rclpy.WaitSet(*counts, self._context.handle)
                wait_set.clear_entities()
                for entry in subscriptions:
                    wait_set.add_subscription(entry[1])
                for entry in clients:
                    wait_set.add_client(entry[1])
                for entry in services:
                    wait_set.add_service(entry[1])
                for entry in timers:
                    wait_set.add_timer(entry[1])
                for entry in guards:
                    wait_set.add_guard_condition(entry[1])
                for entry in waitables:
                    entry[0].add_to_wait_set(wait_set)

                wait_ns = timeout_ns
                if deadline_ns is not None:
                    wait_ns = max(0, deadline_ns - time.monotonic_ns())
                if not poll and wait_ns != 0:  # back for the next poll
                    until_poll_ns = max(0, self._next_poll_ns - time.monotonic_ns())
                    wait_ns = until_poll_ns if wait_ns < 0 else min(wait_ns, until_poll_ns)
                wait_set.wait(wait_ns)
                if self._is_shutdown:
                    raise ShutdownException()
                if not self._context.ok():
                    raise ExternalShutdownException()

                subs_ready = set(wait_set.get_ready_entities("subscription"))
                guards_ready = set(wait_set.get_ready_entities("guard_condition"))
                timers_ready = set(wait_set.get_ready_entities("timer"))
                clients_ready = set(wait_set.get_ready_entities("client"))
                services_ready = set(wait_set.get_ready_entities("service"))
                for entry in guards:  # guard conditions are taken by the wait
                    if entry[2] in guards_ready:
                        entry[0]._executor_triggered = True
                ready_waitables = {e[0] for e in waitables if e[0].is_ready(wait_set)}
            finally:
                for handle in reversed(entered):
                    handle.__exit__(None, None, None)

            if ready_waitables:
                for node, entities in zip(nodes_to_use, of_node, strict=True):
                    for entry in entities.waitables:
                        waitable = entry[0]
                        if (waitable in ready_waitables
                                and waitable.callback_group.can_execute(waitable)):
                            yielded_work = True
                            yield self._make_handler(waitable, node, self._take_waitable), \
                                waitable, node
            for node, entities in zip(nodes_to_use, of_node, strict=True):
                if timers_ready:
                    for tmr, handle, pointer in entities.timers:
                        if (pointer in timers_ready and handle.is_timer_ready()
                                and tmr.callback_group.can_execute(tmr)):
                            yielded_work = True
                            yield self._make_handler(tmr, node, self._take_timer), tmr, node
                if subs_ready:
                    yielded_work |= yield from self._hand_out(
                        node, entities.subscriptions, subs_ready, self._take_subscription)
                for entry in entities.guards:
                    gc = entry[0]
                    if gc._executor_triggered and gc.callback_group.can_execute(gc):
                        yielded_work = True
                        yield self._make_handler(gc, node, self._take_guard_condition), gc, node
                if clients_ready:
                    yielded_work |= yield from self._hand_out(
                        node, entities.clients, clients_ready, self._take_client)
                if services_ready:
                    yielded_work |= yield from self._hand_out(
                        node, entities.services, services_ready, self._take_service)

            if timeout_ns == 0 or (deadline_ns is not None
                                   and time.monotonic_ns() >= deadline_ns):
                raise TimeoutException()
        if self._is_shutdown:
            raise ShutdownException()
        if condition():
            raise ConditionReachedException()

    def _entities(self, node: Any) -> _Entities:
        """`node`'s entities as the wait loop uses them: the same as last round while the
        node's lists hold the same entities (the comparison of identities is C-speed)."""
        lists = _lists_of(node)
        entities = self._entities_of.get(node)
        if entities is None or entities.lists != lists:
            entities = self._entities_of[node] = _Entities(
                tuple(list(kind) for kind in lists))
        return entities

    def _hand_out(self, node, entries: list, ready: set, take: Callable):
        """Handlers for the entities (entries of `_Entities`) whose handle the wait found
        ready, as rclpy makes them; returns whether it made any."""
        handed = False
        for entity, _handle, pointer in entries:
            if pointer in ready and entity.callback_group.can_execute(entity):
                handed = True
                yield self._make_handler(entity, node, take), entity, node
        return handed


def _wake(guard: Any) -> None:
    """Trigger the executor's guard condition, unless `shutdown()` has destroyed it."""
    try:
        guard.trigger()
    except InvalidHandle:
        pass


def _entry(entity: Any) -> tuple | None:
    """(entity, handle, handle's pointer) for a subscription, timer, client, service or guard
    condition; None once it is destroyed."""
    try:
        handle = entity.handle
        return entity, handle, handle.pointer
    except InvalidHandle:
        return None


def _lists_of(node: Any) -> tuple:
    """The node's lists of subscriptions, timers, clients, services, guard conditions and
    waitables: rclpy's own lists where its Node has them (its properties are generators,
    which cost the wait loop a Python step per entity and round), else copies."""
    try:
        return (node._subscriptions, node._timers, node._clients, node._services,
                node._guards, node._Node__waitables)
    except AttributeError:
        return (list(node.subscriptions), list(node.timers), list(node.clients),
                list(node.services), list(node.guards), list(node.waitables))


def _waitable_entry(waitable: Any) -> tuple:
    """(waitable, itself, its entity counts as rclpy's WaitSet takes them); all fixed for its
    life."""
    n = waitable.get_num_entities()
    return (waitable, waitable, (n.num_subscriptions, n.num_guard_conditions, n.num_timers,
                                 n.num_clients, n.num_services, n.num_events))


class _Entities:
    """One node's entities as the wait loop uses them, made when its lists change: entries of
    (entity, handle, pointer) per kind, and of `_waitable_entry` for its waitables, each also
    without the `polled` ones. An entity destroyed while it was listed is left out (rclpy
    leaves it out of the wait set)."""

    __slots__ = ("lists", "subscriptions", "timers", "clients", "services", "guards",
                 "waitables", "unpolled_services", "unpolled_waitables")

    def __init__(self, lists: tuple) -> None:
        self.lists = lists
        self.subscriptions, self.timers, self.clients, self.services, self.guards = (
            [e for e in map(_entry, kind) if e is not None] for kind in lists[:5])
        self.waitables = [_waitable_entry(w) for w in lists[5]]
        self.unpolled_services = [e for e in self.services if not polled(e[0])]
        self.unpolled_waitables = [e for e in self.waitables if not polled(e[0])]


class _GroupVerdicts:
    """`Executor.can_execute` over one round, asking each callback group once: rclpy's two
    groups answer the same for all their entities (a mutually exclusive one: whether none of
    them is running), so the answer is kept for the round; any other group is asked for each
    entity."""

    __slots__ = ("_verdicts",)
    _SAME_FOR_ALL = (MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup)

    def __init__(self) -> None:
        self._verdicts: dict = {}

    def __call__(self, entity: Any) -> bool:
        if entity._executor_event:
            return False
        group = entity.callback_group
        verdict = self._verdicts.get(group)
        if verdict is None:
            verdict = group.can_execute(entity)
            if type(group) in self._SAME_FOR_ALL:
                self._verdicts[group] = verdict
        return verdict


def _enter(entries: list, entered: list) -> list:
    """The entries whose handle could be marked in use, each handle added to `entered`; a
    destroyed one is left out."""
    kept = []
    for entry in entries:
        if entry is None:
            continue
        try:
            entry[1].__enter__()
        except InvalidHandle:
            continue
        entered.append(entry[1])
        kept.append(entry)
    return kept


class BackgroundSpin:
    """Spins `executor` in a daemon thread until `stop()` or until its context shuts down.

    spin_once in slices of `slice_s`, not spin(): the thread leaves its loop within a slice of
    `stop()`, so the executor can then be shut down and the nodes destroyed without a handle
    going away under the spinning thread (the order node_runner.spin_nodes keeps too)."""

    def __init__(self, executor: Executor, slice_s: float = 0.05) -> None:
        self.executor, self.slice_s = executor, slice_s
        self._leave = threading.Event()
        self._thread = threading.Thread(target=self._spin, name="background spin", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._leave.is_set() and self.executor.context.ok():
            self.executor.spin_once(timeout_sec=self.slice_s)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Leave the loop and wait (at most `timeout_s`) for the thread to end."""
        self._leave.set()
        self._thread.join(timeout=timeout_s)
