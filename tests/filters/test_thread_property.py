"""Property test (issue 33): whatever times two threads ask one filter for, in whatever
order, and whatever time steps the input has (some of them unreadable), every answer is
either the step asked for (or, between steps, the step the input delivered, as the
output says) or an error naming the time; never another step's illumination. Derandomized,
so CI runs the same examples every time."""

import threading

import numpy as np
import pytest
from conftest import CountingTimeSource
from vtkmodules.vtkCommonDataModel import vtkDataObject
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as SDDP

from vtkillum.filters.base import IlluminationFilterBase
from vtkillum.io.convert import point_array

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

MEAN_X = 1.75  # mean of world x over the source's 8 points at spacing 0.5


class MeanFilter(IlluminationFilterBase):
    """The input's mean on every point (the source's scalars are ``time + x``)."""

    def compute(self, volume, params):
        return {"mean": np.full(params.output_shape, volume.scalars.mean(), np.float32)}


class Source(CountingTimeSource):
    """Steps ``times``; a step in ``unreadable`` is answered with the nearest readable step
    before it (the first step is always readable)."""

    def __init__(self, times, unreadable):
        super().__init__(times=times)
        self.unreadable = set(unreadable)

    def RequestData(self, request, inInfo, outInfo):
        info = outInfo.GetInformationObject(0)
        if info.Has(SDDP.UPDATE_TIME_STEP()):
            t = info.Get(SDDP.UPDATE_TIME_STEP())
            step = max([s for s in self.times if s <= t] or [self.times[0]])
            if step in self.unreadable:  # never read: the nearest readable step before it
                info.Set(SDDP.UPDATE_TIME_STEP(), max(s for s in self.times
                                                      if s < step and s not in self.unreadable))
        return super().RequestData(request, inInfo, outInfo)


@st.composite
def cases(draw):
    n = draw(st.integers(2, 5))
    times = sorted(draw(st.sets(st.integers(0, 20), min_size=n, max_size=n)))
    unreadable = draw(st.sets(st.sampled_from(times[1:])))
    asks = st.lists(st.one_of(st.sampled_from(times), st.integers(0, 20)), min_size=3,
                    max_size=12)
    cache_mb = draw(st.sampled_from([0.0, 0.002, 1.0]))
    return [float(t) for t in times], [float(t) for t in unreadable], \
        [[float(t) for t in draw(asks)] for _ in range(2)], cache_mb


@settings(max_examples=25, derandomize=True, deadline=None, database=None)
@given(case=cases())
def test_two_threads_get_their_own_step_or_an_error(case):
    times, unreadable, asks, cache_mb = case
    source = Source(times, unreadable)
    f = MeanFilter()
    f.SetInputConnection(source.GetOutputPort())
    f.SetCacheSizeMB(cache_mb)
    wrong, crashed = [], []

    def work(i):
        try:
            for t in asks[i]:
                try:
                    out = f.execute(time=t)
                except ValueError as err:
                    if not (t in times and t in unreadable and f"time {t:g} was requested"
                            in str(err)):
                        wrong.append(("error", t, str(err)[:80]))
                    continue
                step = out.GetInformation().Get(vtkDataObject.DATA_TIME_STEP())
                mean = float(point_array(out, "mean")[0, 0, 0])
                if t in times and t in unreadable:
                    wrong.append(("no error", t, step))
                elif (t in times and step != t) or abs(mean - (step + MEAN_X)) > 1e-5:
                    # a step of its own asked for: that step; any request: the output's
                    # illumination is that of the step it says it is
                    wrong.append(("step", t, step, mean))
        except Exception as err:  # noqa: BLE001 - reported below
            crashed.append(err)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=60)
    assert not crashed and not wrong, (crashed, wrong)
