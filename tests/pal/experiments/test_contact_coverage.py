"""Coverage per contact regime of the smooth and the gated displacement on a tiny babbling run."""

from dataclasses import replace

import numpy as np
import pytest

from pal.agent import build_graph, build_model, fit_model
from pal.experiments.closed_loop.setup import TINY_SETUP, babbled_agent, contact_coverage, split_rows


@pytest.mark.slow
def test_contact_coverage_splits_the_rows_by_the_touch_sensor_for_both_forms():
    setup = replace(TINY_SETUP, babble_steps=40)
    agent = babbled_agent(setup, 0)
    train, test = split_rows(len(agent.history), 0.25)
    touched = agent.history.array("touch")[test] > 0
    results = {}
    for form in ("smooth", "gated"):
        m = replace(setup.agent.model, displacement=form)
        graph = build_graph(agent.spec, (agent.low, agent.high), displacement=form)
        model = build_model(agent.spec, graph, m, seed=0)
        fit_model(model, agent.history, agent.spec, m, source="truth", rows=train, seed=0)
        results[form] = contact_coverage(model, agent.history, m, test, num_samples=50, seed=0)
        again = contact_coverage(model, agent.history, m, test, num_samples=50, seed=0)
        assert again == results[form]
        given = contact_coverage(model, agent.history, m, test, num_samples=50, seed=0, contact_given=True)
        assert given["box"]["all"]["rows"] == len(test)
        for k, o in enumerate(agent.history.objects):
            res = results[form][o]
            assert res["all"]["rows"] == len(test)
            assert res["no contact"]["rows"] == int((~touched[:, k]).sum())
            assert res.get("contact", {"rows": 0})["rows"] == int(touched[:, k].sum())
            assert 0.0 <= res["all"]["coverage"] <= 1.0
            assert np.isfinite(res["sd_no_contact_median_mm"]) and res["sd_no_contact_median_mm"] > 0
