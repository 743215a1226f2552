"""Short fixed mutation-fuzz runs over every reader (tests/python/fuzz_readers.py): the cloud readers
(300 cases), the stroke CSV, the ordering instance JSON and the config YAML (150 cases each). Every
case succeeds or is refused with a one-line ValueError: no crash, hang or other exception.
bench/bench_fuzz_readers.py runs longer ones."""
import numpy as np
import pytest

import fuzz_readers


def test_reader_fuzz_300_cases_without_findings():
    result = fuzz_readers.run(300, seed=1)
    assert result["cases"] == 300 and sum(result["outcomes"].values()) == 300
    assert result["outcomes"].get("refused", 0) > 50 and result["outcomes"].get("read", 0) > 10  # it exercises both
    assert result["findings"] == [], result["findings"]


@pytest.mark.parametrize("target", ["stroke_csv", "ordering_json", "config_yaml"])
def test_text_reader_fuzz_150_cases_without_findings(target):
    result = fuzz_readers.run(150, seed=1, target=target)
    assert result["target"] == target and sum(result["outcomes"].values()) == 150
    assert result["outcomes"].get("refused", 0) > 30 and result["outcomes"].get("read", 0) > 5  # it exercises both
    assert result["findings"] == [], result["findings"]


def test_text_mutations_reach_every_kind_of_hostile_input():
    # the text targets' findings came from these: deep nesting, huge numbers, non-UTF-8 bytes, CRs
    rng = np.random.default_rng(1)
    seed_file = fuzz_readers.config_seeds()["partial.yaml"]
    cases = [fuzz_readers.mutate_text(seed_file, rng) for _ in range(400)]
    assert any(b"[" * 1000 in c or b"{" * 1000 in c for c in cases)
    assert any(b"9" * 400 in c or b"1e309" in c for c in cases)
    assert any(b"*l1" in c for c in cases)  # nested aliases
    assert sum(not _is_utf8(c) for c in cases) > 10 and sum(b"\r" in c for c in cases) > 5
    assert len(set(cases)) > 350  # nearly every case differs (a one-byte prefix alone may repeat)


def _is_utf8(data: bytes) -> bool:
    try:
        data.decode("utf-8")
        return True
    except UnicodeDecodeError:
        return False
