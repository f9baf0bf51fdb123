"""Right under threads and time: no filter passes off another step's illumination as the one
requested, the cache keys on what was computed, and updates from several threads (with
transfer-function edits among them) give each caller a consistent result."""

import threading

import numpy as np
import pytest
from conftest import CountingTimeSource
from vtkmodules.vtkCommonDataModel import vtkDataObject

from vtkillum.core.transfer_function import TransferFunction
from vtkillum.filters.base import PIPELINE_LOCK, IlluminationFilterBase
from vtkillum.io.convert import point_array


class MeanFilter(IlluminationFilterBase):
    """The input's mean (which carries its time: scalars are ``time + x``) and the opacity of
    a fixed value under the transfer function, on every point."""

    def __init__(self):
        super().__init__()
        self.executions = 0

    def compute(self, volume, params):
        self.executions += 1
        shape = params.output_shape
        return {"mean": np.full(shape, volume.scalars.mean(), np.float32),
                "alpha": np.full(shape, params.transfer_function.alpha(1.0), np.float32)}


class GappySource(CountingTimeSource):
    """Announces steps 0, 1, 2 but cannot read step 1: asked for it, it delivers step 0 (what
    a series reader does when a file of the series is missing)."""

    def RequestData(self, request, inInfo, outInfo):
        from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP

        info = outInfo.GetInformationObject(0)
        if info.Has(SDDP.UPDATE_TIME_STEP()) and info.Get(SDDP.UPDATE_TIME_STEP()) == 1.0:
            info.Set(SDDP.UPDATE_TIME_STEP(), 0.0)
        return super().RequestData(request, inInfo, outInfo)


def time_of(output) -> float:
    return output.GetInformation().Get(vtkDataObject.DATA_TIME_STEP())


MEAN_X = 1.75  # mean of world x over the source's 8 points at spacing 0.5


def test_a_missing_step_is_an_error_and_never_cached():
    source = GappySource()
    f = MeanFilter()
    f.SetInputConnection(source.GetOutputPort())
    for _ in range(2):  # the second request must not be served a cached wrong step
        with pytest.raises(ValueError, match=r"time 1 was requested.*\(0, 1, 2\).*delivered "
                                             r"time 0.*missing"):
            f.execute(time=1.0)
    for t in (0.0, 2.0, 0.0):
        out = f.execute(time=t)
        assert time_of(out) == t
        assert point_array(out, "mean")[0, 0, 0] == pytest.approx(t + MEAN_X)
    assert f.GetCacheStatistics().entries == 2


def test_a_time_between_steps_gets_the_step_delivered_and_is_cached_under_it():
    source = CountingTimeSource()
    f = MeanFilter()
    f.SetInputConnection(source.GetOutputPort())
    out = f.execute(time=0.5)  # the source takes the step at or before: 0
    assert time_of(out) == 0.0
    assert point_array(out, "mean")[0, 0, 0] == pytest.approx(0.0 + MEAN_X)
    assert time_of(f.execute(time=2.0)) == 2.0  # (so that the next request is not a no-op)
    runs = f.executions
    out = f.execute(time=0.0)  # cached under the step computed, not the time requested
    assert time_of(out) == 0.0 and f.executions == runs
    f.execute(time=2.0)
    out = f.execute(time=0.5)  # and the request it answered maps to it
    assert time_of(out) == 0.0 and f.executions == runs
    assert f.GetCacheStatistics().entries == 2


def run_threads(work, threads=2):
    errors = []

    def guarded(i):
        try:
            work(i)
        except Exception as err:  # noqa: BLE001 - reported by the test
            errors.append(err)

    pool = [threading.Thread(target=guarded, args=(i,)) for i in range(threads)]
    for thread in pool:
        thread.start()
    for thread in pool:
        thread.join(timeout=120)
    assert not errors, errors


def test_one_filter_updated_from_two_threads():
    source = CountingTimeSource(times=[0.0, 1.0, 2.0, 3.0])
    f = MeanFilter()
    f.SetInputConnection(source.GetOutputPort())
    f.SetCacheSizeMB(0.01)  # smaller than two outputs: most updates execute
    wrong = []

    def work(i):
        for k in range(40):
            t = float((i + k) % 4)
            out = f.execute(time=t)
            if time_of(out) != t or point_array(out, "mean")[0, 0, 0] != \
                    pytest.approx(t + MEAN_X):
                wrong.append((t, time_of(out)))

    run_threads(work)
    assert not wrong
    for t in (3.0, 0.0, 2.0):  # the cache was not poisoned either
        out = f.execute(time=t)
        assert time_of(out) == t and point_array(out, "mean")[0, 0, 0] == \
            pytest.approx(t + MEAN_X)


def test_two_filters_sharing_a_source_in_two_threads():
    source = CountingTimeSource(times=[0.0, 1.0, 2.0])
    filters = [MeanFilter(), MeanFilter()]
    for f in filters:
        f.SetInputConnection(source.GetOutputPort())
    wrong = []

    def work(i):
        for k in range(30):
            t = float((i + 2 * k) % 3)
            out = filters[i].execute(time=t)
            if point_array(out, "mean")[0, 0, 0] != pytest.approx(t + MEAN_X):
                wrong.append((i, t))

    run_threads(work)
    assert not wrong


def test_a_transfer_function_edit_during_updates_gives_old_or_new():
    source = CountingTimeSource()
    f = MeanFilter()
    f.SetInputConnection(source.GetOutputPort())
    old = TransferFunction([0.0, 10.0], [0.1, 0.1], [[1, 1, 1], [1, 1, 1]])
    new = TransferFunction([0.0, 10.0], [0.7, 0.7], [[1, 0, 0], [1, 0, 0]])
    f.SetTransferFunction(old)
    seen = []
    stop = threading.Event()

    def work(i):
        if i == 0:
            while not stop.is_set():
                seen.append(float(point_array(f.execute(time=0.0), "alpha")[0, 0, 0]))
        else:
            for k in range(60):
                f.SetTransferFunction(new if k % 2 == 0 else old)
            stop.set()

    run_threads(work)
    assert seen
    assert set(np.round(seen, 6)) <= {0.1, 0.7}


def test_editing_a_vtk_function_under_the_lock_is_atomic():
    from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction

    source = CountingTimeSource()
    f = MeanFilter()
    f.SetInputConnection(source.GetOutputPort())
    opacity = vtkPiecewiseFunction()
    opacity.AddPoint(0.0, 0.2)
    opacity.AddPoint(10.0, 0.2)
    f.SetScalarOpacity(opacity)
    seen = []
    stop = threading.Event()

    def work(i):
        if i == 0:
            while not stop.is_set():
                seen.append(float(point_array(f.execute(time=0.0), "alpha")[0, 0, 0]))
        else:
            for k in range(60):
                value = 0.6 if k % 2 == 0 else 0.2
                with PIPELINE_LOCK:  # a multi-step edit: the documented way
                    opacity.RemoveAllPoints()
                    opacity.AddPoint(0.0, value)
                    opacity.AddPoint(10.0, value)
            stop.set()

    run_threads(work)
    assert seen and set(np.round(seen, 6)) <= {0.2, 0.6}
