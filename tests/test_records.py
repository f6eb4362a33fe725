"""Record formats: a record is upgraded one version step at a time, and one the steps cannot reach, of a
newer version or of another format is refused in one line naming its format."""

import pytest

from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import changed_fields
from base_suites.runtime.records import NOT_RECORDED, RecordFormat, fill_missing

FORMAT = RecordFormat(
    "demo-record",
    3,
    {
        1: lambda r: fill_missing(r, {"chunk": 1, "jiti": {"warmup": "base"}, "size": lambda r: 2 * r["n"]}),
        2: lambda r: {**{k: v for k, v in r.items() if k != "old"}, "renamed": r.get("old")},
    },
)


def test_a_record_is_upgraded_one_step_at_a_time_to_the_current_version():
    v1 = {"n": 3, "jiti": {}, "old": "x"}
    assert FORMAT.upgrade(v1, "r.json") == {
        "n": 3,
        "chunk": 1,
        "jiti": {"warmup": "base"},
        "size": 6,
        "renamed": "x",
        "format": "demo-record/3",
    }
    assert v1 == {"n": 3, "jiti": {}, "old": "x"}  # the record read is left as it was
    v2 = {"format": "demo-record/2", "chunk": 8, "old": "y"}
    assert FORMAT.upgrade(v2, "r.json") == {"format": "demo-record/3", "chunk": 8, "renamed": "y"}
    current = {"format": "demo-record/3", "chunk": 4}
    assert FORMAT.upgrade(current, "r.json") == current


def test_records_the_steps_cannot_read_are_refused_in_one_line_naming_the_format():
    later = RecordFormat("demo-record", 3, {2: lambda r: r})
    with pytest.raises(
        UserInputError, match=r"r.json: field 'format' is None \(version 1\), older than .* demo-record/2"
    ):
        later.upgrade({"n": 1}, "r.json")
    with pytest.raises(UserInputError, match="r.json: field 'format' is 'demo-record/4', newer than"):
        FORMAT.upgrade({"format": "demo-record/4"}, "r.json")
    with pytest.raises(UserInputError, match="r.json: field 'format' is 'other/3'; expected 'demo-record/3'"):
        FORMAT.upgrade({"format": "other/3"}, "r.json")
    with pytest.raises(UserInputError, match="r.json: expected a demo-record record"):
        FORMAT.upgrade([1, 2], "r.json")


def test_a_setting_not_recorded_compares_equal_to_anything():
    assert changed_fields({"a": NOT_RECORDED, "b": 1}, {"a": "now", "b": 1}) == []
    assert changed_fields({"a": 1, "jiti": {"x": 1}}, {"a": 1, "jiti": {"x": 2}}) == [("jiti.x", 1, 2)]
