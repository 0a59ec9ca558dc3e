"""The run kind ``filter_predict`` (filter ``kfp``): a run kind added as its entry
(derive.runs.unit.RUN_KINDS) and its builder (derive.runs.kinds.BUILDERS), both languages
printed from the builder; the generated Python and C against the NumPy reference."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_rts import measurements, with_gaps

from derive import catalog
from derive.apps.verify import relative_error
from derive.pipeline import load_generated
from derive.reference.linear import kf, predictions
from derive.runs import kinds
from derive.runs.unit import RUN_KINDS

#: Generated against the reference, linear filter in double (the KF's own bound).
GENERATED_TOLERANCE = 1e-12
ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", ["cv"])
def test_filtered_and_predicted_equal_the_reference(name):
    num = catalog.load(name).numeric()
    generated = load_generated(name, "kfp", {"missing": True})
    zs = with_gaps(measurements(num), seed=3, whole_rows=False)
    xr, Pr = kf(num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0, zs, skip_nan=True)
    xpr, Ppr = predictions(num.F, num.G, num.Q, num.x0, num.P0, xr, Pr)
    n = len(num.x0)
    for lang in ("python", "c"):
        xs, Ps, xps, Pps = generated.module(lang).run(zs, num.x0, num.P0)
        for got, want in ((xs, xr), (Ps, Pr), (xps, xpr), (Pps, Ppr)):
            got = np.asarray(got).reshape(want.shape)
            assert relative_error(got, want) <= GENERATED_TOLERANCE, (name, lang)
    assert xr.shape == (len(zs), n)


def test_the_kind_is_its_entry_and_its_builder():
    kind = RUN_KINDS["filter_predict"]
    assert [array for array, *_ in kind.stores] == ["xs", "Ps", "x_preds", "P_preds"]
    assert kinds.BUILDERS["filter_predict"] is kinds.stepping
    for lang in ("c", "python"):
        assert not (ROOT / "templates" / lang / "filter_predict.jinja").exists()
