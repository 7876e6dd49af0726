"""Hypothesis profiles for the suite.

``ci`` (the default) makes every property test draw the same examples on every run and every machine
(``derandomize``), so a test that passed here passes in CI and a failure there is reproducible here. It
reports the first failing example with its reproduction blob at once, without shrinking it: shrinking a
long stream through the compiled loop can outlast pytest-timeout's 300 s, and the timeout then hides the
failure behind hypothesis's "inconsistent data generation" (seen once in CI on test_fuser_any_input.py).

``search`` draws fresh random examples, shrinks what fails and explains it, for a wider search run by hand:

    python -m pytest -n 0 --timeout 0 --hypothesis-profile search tests/test_fuser_any_input.py

(or ``--hypothesis-seed N`` with it, to repeat one search). Tests that set ``max_examples`` keep their own
count in both profiles; ``search`` multiplies the others' by ten.
"""

from __future__ import annotations

from hypothesis import Phase, settings

settings.register_profile(
    "ci", derandomize=True, print_blob=True, phases=(Phase.explicit, Phase.reuse, Phase.generate)
)
settings.register_profile("search", derandomize=False, print_blob=True, max_examples=1_000)
settings.load_profile("ci")
