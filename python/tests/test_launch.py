"""The command line, the scenario fields and the duty bookkeeping of a
Python controller, without a loop."""

import math
import pathlib
import re
import tempfile
import unittest

from flexloop.launch import (
    AT_START,
    REPLACEMENT,
    RESTART,
    STANDBY,
    Params,
    ScenarioError,
    Setup,
    UsageError,
    load_settings,
    parse_args,
)
from flexloop.runner import _Standing

_BASE = ["--scenario", "s.toml", "--prefix", "flx1_", "--run-dir", "r"]


class CommandLine(unittest.TestCase):
    def test_the_supervisors_flags_parse(self):
        a = parse_args(["--generation", "3", "--join", *_BASE, "--rate", "1000", "--mode",
                        "lockstep", "--no-realtime", "--tick", "sleep", "--duration", "0"])
        self.assertEqual((a.generation, a.joining, a.prefix), (3, REPLACEMENT, "flx1_"))
        self.assertEqual((a.rate_hz, a.mode, a.no_realtime), (1000.0, "lockstep", True))
        self.assertEqual(parse_args(_BASE).joining, AT_START)
        self.assertEqual(parse_args(["--restart", *_BASE]).joining, RESTART)
        self.assertEqual(parse_args(["--standby", *_BASE]).joining, STANDBY)

    def test_the_programs_own_arguments_come_before_the_last_double_dash(self):
        a = parse_args(["--gain", "2", "--", "x", "--", *_BASE, "--join"])
        self.assertEqual((a.own, a.joining), (["--gain", "2", "--", "x"], REPLACEMENT))
        self.assertEqual(parse_args(_BASE).own, [])

    def test_what_it_cannot_serve_is_a_usage_error(self):
        for argv, says in [
            (["--spare", *_BASE], "spare"),
            (["--join", "--restart", *_BASE], "not allowed with"),
            (["--prefix", "p"], "required"),
            ([*_BASE, "--mode", "fast"], "invalid choice"),
            ([*_BASE, "--unknown"], "unrecognized"),
        ]:
            with self.subTest(argv=argv), self.assertRaisesRegex(UsageError, says):
                parse_args(argv)


def _settings(text, *flags):
    d = tempfile.mkdtemp()
    path = pathlib.Path(d) / "s.toml"
    path.write_text(text)
    return load_settings(parse_args(["--scenario", str(path), "--prefix", "p", "--run-dir", d,
                                     *flags]))


class Scenario(unittest.TestCase):
    def test_overrides_win_and_lockstep_or_no_realtime_drop_the_priority(self):
        text = '[loop]\nrate_hz = 2000\n[realtime]\ncontroller = { priority = 81, cpu = 0 }\n'
        s = _settings(text)
        self.assertEqual((s.rate_hz, s.mode, s.realtime.priority), (2000.0, "realtime", 81))
        self.assertEqual(s.period_ns, 500_000)
        s = _settings(text, "--rate", "1000", "--mode", "lockstep")
        self.assertEqual((s.rate_hz, s.lockstep, s.realtime.priority), (1000.0, True, None))
        s = _settings(text, "--no-realtime")
        self.assertEqual((s.realtime.priority, s.realtime.lock_memory), (None, False))

    def test_bad_fields_name_the_file_and_the_field(self):
        for text, field in [
            ("[loop]\nrate_hz = -1\n", "loop.rate_hz"),
            ("[loop]\nmode = 3\n", "loop.mode"),
            ("[loop]\ncommand_deadline_us = 100.0\n", "loop.command_deadline_us"),
            ("[controller]\nparams = 1\n", "controller.params"),
            ("[controller]\nextra_delay_samples = 2\n", "controller.extra_delay_samples"),
            ("[plant]\ninput_limit = 0\n", "plant.input_limit"),
            ("[realtime]\ncontroller = { priority = 200 }\n", "realtime.controller.priority"),
            ("[reference]\nshape = \"ramp\"\n", "reference.shape"),
        ]:
            with self.subTest(field=field):
                with self.assertRaisesRegex(
                    ScenarioError, rf"^scenario .*s\.toml: field `{re.escape(field)}`: "
                ):
                    _settings(text)
        with self.assertRaisesRegex(ScenarioError, r"^scenario .*s\.toml: cannot parse: "):
            _settings("[loop\n")
        with self.assertRaisesRegex(ScenarioError, r"^scenario .*nothing\.toml: cannot read: "):
            load_settings(parse_args(["--scenario", "nothing.toml", "--prefix", "p",
                                      "--run-dir", "r"]))

    def test_the_deadline_and_the_loop_delay_are_the_setups(self):
        s = Setup(_settings("[loop]\nrate_hz = 10000\ncommand_deadline_us = 30.0\n"))
        self.assertEqual((s.command_deadline_s, s.loop_delay_samples), (30.0 / 1e6, 1))
        s = Setup(_settings("[controller]\nextra_delay_samples = 1\n"))
        self.assertEqual((s.command_deadline_s, s.loop_delay_samples), (None, 2))
        with self.assertRaisesRegex(ScenarioError, "cannot also wait an extra sample"):
            _settings("[loop]\ncommand_deadline_us = 30\n[controller]\nextra_delay_samples = 1\n")

    def test_the_reference_is_the_controllers(self):
        s = _settings("[reference]\nshape = \"sine\"\namplitude = 0.001\nfrequency_hz = 2.0\n")
        r = Setup(s).reference()
        t = 0.1234
        self.assertEqual(r.sample(t), 0.001 * math.sin(2.0 * math.pi * 2.0 * t))
        self.assertEqual(r.derivatives(t)[0], r.sample(t))
        s = _settings("[reference]\nshape = \"step\"\namplitude = 2.0\nstart_s = 0.5\n")
        r = Setup(s).reference()
        self.assertEqual((r.sample(0.4), r.sample(0.5)), (0.0, 2.0))
        self.assertEqual(Setup(_settings("")).reference().sample(3.0), 0.0)
        self.assertIsNone(Setup(s).reference_direction)
        s = _settings("[plant]\nmodel = \"mimo-example\"\n[reference]\nshape = \"scan\"\n"
                      "start_s = 0.01\ndirection = [1.0, -0.5]\n")
        self.assertEqual(Setup(s).reference_direction, (1.0, -0.5))
        self.assertAlmostEqual(Setup(s).reference().sample(0.2), 0.17, delta=1e-12)
        with self.assertRaisesRegex(ScenarioError, "field `reference.start_s`: a scan must start"):
            Setup(_settings("[reference]\nshape = \"scan\"\n")).reference()
        with self.assertRaisesRegex(ScenarioError, "field `reference.direction`: has 3 entries"):
            Setup(_settings("[plant]\nmodel = \"mimo-example\"\n[reference]\nshape = \"step\"\n"
                            "direction = [1.0, 0.0, 1.0]\n")).reference()


class ControllerParams(unittest.TestCase):
    def test_numbers_are_checked_and_unread_ones_refused(self):
        p = Params("s.toml", {"kp": 2, "kd": "x", "extra": 1.0})
        self.assertEqual(p.number("kp"), 2.0)
        self.assertEqual(p.number("ki", default=0.5), 0.5)
        with self.assertRaisesRegex(ScenarioError, "`controller.params.kd`: must be a number"):
            p.number("kd")
        with self.assertRaisesRegex(ScenarioError, "`controller.params.n`: missing"):
            p.number("n")
        with self.assertRaisesRegex(ScenarioError, "`controller.params.extra`: unknown"):
            p.check_all_read()
        with self.assertRaisesRegex(ScenarioError, "must be positive"):
            Params("s.toml", {"n": 0.0}).number("n", positive=True)


class Duty(unittest.TestCase):
    """The cases of shared/node duty.rs's tests, on the Python twin."""

    def test_the_first_instance_is_active_at_once(self):
        s = _Standing(0, late=False)
        self.assertTrue(s.priority_raised)
        duty, was, raise_priority = s.on_sample(0, 0, 0, 0, True)
        self.assertEqual((duty, was, raise_priority), ("active", "shadow", False))

    def test_a_replacement_raises_its_priority_when_named_and_caught_up_then_takes_over(self):
        s = _Standing(1, late=True)
        self.assertEqual(s.on_sample(10, 10, 0, 0, True), ("shadow", "shadow", False))
        self.assertFalse(s.on_sample(11, 11, 0, 1, False)[2], "named but behind")
        self.assertEqual(s.on_sample(12, 12, 0, 1, True), ("shadow", "shadow", True))
        self.assertEqual(s.on_sample(13, 13, 1, 1, True), ("active", "shadow", False))
        self.assertEqual(s.on_sample(14, 14, 2, 2, True)[0], "retiring")

    def test_a_standby_stands_by_until_promoted(self):
        s = _Standing(3, late=True, standby=True)
        self.assertEqual(s.on_sample(7, 7, 0, 0, True)[0], "standby")
        self.assertEqual(s.on_sample(8, 8, 3, 3, True)[:2], ("active", "standby"))

    def test_skipped_measurements_count_as_the_rust_instance_counts_them(self):
        shadow = _Standing(1, late=True)
        shadow.on_sample(0, 0, 0, 0, True)
        shadow.on_sample(5, 3, 0, 0, False)
        self.assertEqual(shadow.skipped, 2)
        active = _Standing(0, late=False)
        active.on_sample(0, 0, 0, 0, True)
        active.on_sample(5, 3, 0, 0, False)
        self.assertEqual(active.skipped, 4)


if __name__ == "__main__":
    unittest.main()
