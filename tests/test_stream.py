"""Streaming tasks through one wavefront (path.hand_over): each task handed back is
exactly what rendering it alone gives, in order, with at most HELD_TASKS held."""

import numpy as np
import pytest

from wavefront import load_scene
from wavefront import path
from wavefront.path import HELD_TASKS, TaskStream, TraceStats, trace_paths
from wavefront.render import execute
from wavefront.sampling import scene_key
from wavefront.units import Job, plan_units

from .test_furnace import SCENES


class ListStream(TaskStream):
    """Tasks from a list, given only when asked; results kept in order."""

    def __init__(self, scene, tasks):
        self.scene, self.tasks, self.results, self.most_held = scene, list(tasks), [], 0
        self.given = 1  # the first goes to trace_paths itself

    def job(self, units):
        return Job(units, self.scene.width, self.scene.render.samples_per_pixel)

    def next_job(self, idle):
        if self.given == len(self.tasks):
            return None
        self.given += 1
        self.most_held = max(self.most_held, self.given - len(self.results))
        return self.job(self.tasks[self.given - 1])

    def finished(self, job, stats, radiance):
        assert job.units == self.tasks[len(self.results)]  # in order
        self.results.append((job.reduce(radiance), stats))


def tasks_of(units, sizes):
    """``units`` cut into consecutive tasks of ``sizes`` units (the rest in the last)."""
    out, i = [], 0
    for n in sizes:
        out.append(units[i:i + n])
        i += n
    return out + ([units[i:]] if i < len(units) else [])


def streamed_and_alone(scene_name, sizes):
    """Each task's per-unit results and counters streamed through one wavefront, and rendered alone."""
    scene = load_scene(SCENES / f"{scene_name}.yaml").with_overrides(width=96, height=64, samples_per_pixel=8)
    cs, key = scene.compile(), scene_key(scene.render.seed)
    units = list(plan_units(scene.width, scene.height, scene.render.samples_per_pixel))
    tasks = tasks_of(units, sizes)
    capacity = 3000  # a few thousand paths: each task's last paths outlive the next task's start
    alone = [execute(cs, key, capacity, task)[:2] for task in tasks]
    stream = ListStream(scene, tasks)
    with np.errstate(over="ignore", invalid="ignore"):
        assert trace_paths(cs, stream.job(tasks[0]), key, capacity, TraceStats(), stream=stream) is None
    return stream, alone, tasks


def same_results(a, b) -> bool:
    return len(a) == len(b) and all(
        unit_a == unit_b and np.array_equal(sum_a, sum_b) and np.array_equal(count_a, count_b) and da == db
        for (unit_a, sum_a, count_a, da), (unit_b, sum_b, count_b, db) in zip(a, b))


@pytest.mark.parametrize("scene_name, sizes", [
    ("three_spheres", [1, 1, 1, 1, 1, 1]),  # tasks of one unit, many held at once
    ("three_spheres", [1, 6, 1, 9]),  # a small first task, then bigger ones: the buffer grows
    ("cornell_box", [2, 3, 2, 2, 4]),  # light sampling: shadow rays riding with the next query
])
def test_streamed_tasks_are_each_exactly_their_own_render(scene_name, sizes):
    stream, alone, tasks = streamed_and_alone(scene_name, sizes)
    assert len(stream.results) == len(tasks)
    assert 1 < stream.most_held <= HELD_TASKS
    for (streamed, stats), (own, own_stats), task in zip(stream.results, alone, tasks):
        assert stats.samples == own_stats.samples == sum(u.size for u in task)
        # each task's own paths' segments and shadow rays, not whatever ran meanwhile
        assert (stats.segments, stats.shadow_rays) == (own_stats.segments, own_stats.shadow_rays)
        assert same_results(streamed, own)


def test_a_task_handed_back_before_its_last_paths_end_is_caught(monkeypatch):
    """Negative control: a hand-over that ignores the paths still in flight
    (a task handed back once its samples are issued) must fail the comparison."""
    monkeypatch.setattr(path, "lowest_in_flight", lambda next_slot, live, riding: next_slot)
    try:
        stream, alone, _ = streamed_and_alone("three_spheres", [1, 1, 1, 1])
    except IndexError:  # a path whose task has left adds at a slot before the buffer
        return
    assert not all(same_results(streamed, own) for (streamed, _), (own, _) in zip(stream.results, alone))


def test_a_task_handed_back_with_a_few_paths_in_flight_is_caught(monkeypatch):
    """Negative control, subtler: a task handed back while paths of its last
    64 samples may still be in flight (their later terms land outside it)."""
    real = path.lowest_in_flight
    monkeypatch.setattr(path, "lowest_in_flight", lambda next_slot, live, riding: real(next_slot, live, riding) + 64)
    stream, alone, _ = streamed_and_alone("three_spheres", [1, 1, 1, 1])
    assert not all(same_results(streamed, own) for (streamed, _), (own, _) in zip(stream.results, alone))
