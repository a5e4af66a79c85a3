"""The drivers against their simulated twins: SCPI over a real TCP socket through pyvisa-py,
the piezo protocol over a real pseudo-terminal through pyserial."""

from __future__ import annotations

import time

import numpy as np
import pytest
from ops_rig_ros.drivers import ACTUATORS, TRACE_SOURCES, DelayActuator, driver_class
from ops_rig_ros.drivers.base import InstrumentError, TraceSource
from ops_rig_ros.drivers.mdt_piezo import MdtPiezo
from ops_rig_ros.drivers.scpi_scope import ScpiScope, parse_preamble
from ops_rig_ros.simlab.scope_server import ieee_block, normalize


def scope(lab, **options):
    drv = ScpiScope({"resource": lab.scope.resource, "timeout_ms": 300, **options})
    drv.connect()
    return drv


@pytest.mark.parametrize(
    "options",
    [{"format": "BYTE"}, {"format": "WORD"}, {"format": "WORD", "byte_order": "MSBFirst"}],
)
def test_scope_scales_records_to_volts(lab, options):
    drv = scope(lab, **options)
    try:
        record = drv.read().volts
        assert record.size == lab.optics.points
        levels = 256 if options["format"] == "BYTE" else 65536
        step = 1.2 / (levels - 1)  # the simulated scope spans -0.1 .. 1.1 V
        np.testing.assert_allclose(record, lab.scope.state.record, atol=step / 2 + 1e-12)
        assert drv.idn.startswith("OPS,SimScope")
    finally:
        drv.close()


@pytest.mark.parametrize(
    ("fault", "says"),
    [
        ("SHORT", "short waveform"),
        ("HEADER", "waveform read failed"),
        ("NAN", "yincrement is nan"),
        ("SILENT", "Timeout"),
        ("DROP", "waveform read failed"),
    ],
)
def test_scope_garbage_and_timeouts_raise_instrument_error(lab, fault, says):
    drv = scope(lab)
    try:
        lab.scope.fault(fault)
        with pytest.raises(InstrumentError, match=says):
            drv.read()
        drv.connect()  # a fresh session works again
        assert drv.read().volts.size == lab.optics.points
    finally:
        drv.close()


def test_scope_gone_then_back(lab):
    drv = scope(lab)
    try:
        lab.scope.pause(0.6)
        with pytest.raises(InstrumentError):
            drv.read()
        with pytest.raises(InstrumentError, match="cannot connect"):
            drv.connect()
        time.sleep(0.7)  # the scope's pause, not a wait for our own work
        drv.connect()
        assert drv.read().volts.size == lab.optics.points
    finally:
        drv.close()


def test_scope_not_there():
    drv = ScpiScope({"resource": "TCPIP::127.0.0.1::9::SOCKET", "timeout_ms": 200})
    with pytest.raises(InstrumentError, match="cannot connect"):
        drv.connect()


def test_preamble_and_block_helpers():
    pre = parse_preamble("0,2,10,1,1e-9,0,0,0.01,-0.1,0")
    assert pre["points"] == 10 and pre["yincrement"] == 0.01
    with pytest.raises(InstrumentError):
        parse_preamble("0,2,10")
    with pytest.raises(InstrumentError):
        parse_preamble("0,2,10,1,1e-9,0,0,0,-0.1,0")
    assert ieee_block(b"abc") == b"#13abc"
    assert normalize(":WAVeform:PREamble?") == ":WAV:PRE?"


def test_piezo_sets_and_reads_back(lab):
    unit = lab.piezos[0]
    drv = MdtPiezo({"port": unit.device, "channels": ["x", "y", "z"]})
    drv.connect()
    try:
        assert drv.vlimit == 75.0
        drv.set_voltages(np.array([1.5, 22.25, 70.125]))
        np.testing.assert_allclose(drv.read_voltages(), [1.5, 22.25, 70.125], atol=0.006)
        assert unit.received[-3:] == [(0, 1.5), (1, 22.25), (2, 70.125)]
        np.testing.assert_allclose(lab.optics.volts, [1.5, 22.25, 70.125])
        with pytest.raises(InstrumentError):
            drv.set_voltages(np.array([np.nan, 1.0, 1.0]))
        assert all(v == v for _, v in unit.received)  # no NaN was sent
    finally:
        drv.close()


def test_piezo_with_echo_and_silence(lab):
    unit = lab.piezos[0]
    drv = MdtPiezo({"port": unit.device, "channels": ["x"], "timeout_s": 0.2})
    drv.connect()
    try:
        unit.echo = True  # as the unit after a power cycle: the driver strips the echo
        drv.set_voltages(np.array([3.0]))
        assert drv.read_voltages()[0] == pytest.approx(3.0)
        unit.silent = True
        with pytest.raises(InstrumentError, match="no prompt"):
            drv.read_voltages()
    finally:
        unit.silent = False
        drv.close()


def test_piezo_not_there():
    drv = MdtPiezo({"port": "/dev/does-not-exist"})
    with pytest.raises(InstrumentError, match="cannot open"):
        drv.connect()


def test_driver_lookup():
    assert driver_class("scpi_scope", TRACE_SOURCES, TraceSource) is ScpiScope
    assert driver_class("ops_rig_ros.drivers.mdt_piezo:MdtPiezo", ACTUATORS, DelayActuator)
    with pytest.raises(ValueError, match="unknown driver"):
        driver_class("nope", ACTUATORS, DelayActuator)
    with pytest.raises(ValueError, match="is not a DelayActuator"):
        driver_class("scpi_scope", TRACE_SOURCES | ACTUATORS, DelayActuator)


def test_nidaq_actuator():
    from ops_rig_ros.drivers.nidaq_ao import NidaqAnalogOut, driver_missing_reason

    reason = driver_missing_reason()
    if reason:
        drv = NidaqAnalogOut({"channels": ["Dev1/ao0"]})
        with pytest.raises(InstrumentError, match=r"NI-DAQmx|nidaqmx"):
            drv.connect()
        pytest.skip(f"NI-DAQmx analog output not tested: {reason}")
    drv = NidaqAnalogOut({"channels": ["Dev1/ao0"]})
    drv.connect()
    try:
        drv.set_voltages(np.array([0.0]))
        assert drv.read_voltages()[0] == 0.0
    finally:
        drv.close()
