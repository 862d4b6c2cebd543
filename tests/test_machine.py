"""The processor a measurement names: the first CPU's model name with its family and model numbers (``AMD EPYC``
alone does not tell Milan from Genoa), Python's name where /proc/cpuinfo cannot be read."""

from __future__ import annotations

import platform

from evaaa_baselines.machine import processor

CPUINFO = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 17
model name\t: AMD EPYC

processor\t: 1
cpu family\t: 6
model\t\t: 143
model name\t: Intel(R) Xeon(R) Platinum 8481C
"""


def test_the_first_cpu_is_named_with_its_family_and_model(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text(CPUINFO)
    assert processor(info) == "AMD EPYC (family 25, model 17)"
    info.write_text("model name\t: Apple M2\n")
    assert processor(info) == "Apple M2"


def test_without_cpuinfo_python_names_the_processor(tmp_path):
    assert processor(tmp_path / "absent") == (platform.processor() or platform.machine())
