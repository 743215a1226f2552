"""A short fixed mutation-fuzz run over the cloud readers (tests/python/fuzz_readers.py): every
case reads or is refused with a one-line ValueError; no crash, hang or other exception.
bench/run_benchmarks.py runs a longer one."""
import fuzz_readers


def test_reader_fuzz_300_cases_without_findings():
    result = fuzz_readers.run(300, seed=1)
    assert result["cases"] == 300 and sum(result["outcomes"].values()) == 300
    assert result["outcomes"].get("refused", 0) > 50 and result["outcomes"].get("read", 0) > 10  # it exercises both
    assert result["findings"] == [], result["findings"]
