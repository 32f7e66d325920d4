"""The reliability suite's lpam: the one of the fault tests, which stops at the end every
supervisord and app process its root ran (tests/integration/test_fault_truth.py)."""

from tests.integration.test_fault_truth import lpam  # noqa: F401
