"""The SDK's parts without a loop: the set-point and reference (the cases
of shared/control setpoint.rs's and shared/design reference.rs's tests),
the command's parts, the estimate a law returns, the params record, a
restart's merge of replayed and live measurements, the examples' laws.
(tests/integration/python_sdk.rs compares the reference with Rust's over
every scenario and runs the laws in loops.)"""

import importlib.util
import json
import math
import os
import pathlib
import tempfile
import unittest

import flexloop
from flexloop import messages as msg
from flexloop.launch import (
    Params,
    Setup,
    load_settings,
    params_record_path,
    parse_args,
    write_params_record,
)
from flexloop.observer_runner import STASH, _CatchUp, _Process, write_estimate
from flexloop.reference import Reference, Setpoint, SetpointError, SetpointParams
from flexloop.runner import CommandParts

_REPO = pathlib.Path(__file__).resolve().parents[2]


def _settings(text, role="controller", *flags):
    d = tempfile.mkdtemp()
    path = pathlib.Path(d) / "s.toml"
    path.write_text(text)
    return load_settings(
        parse_args(["--scenario", str(path), "--prefix", "p", "--run-dir", d, *flags], role)
    )


def _example(name):
    spec = importlib.util.spec_from_file_location(name, _REPO / "python/examples" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class SetpointTimeline(unittest.TestCase):
    """shared/control setpoint.rs ``table_3_6_timeline``."""

    def test_table_3_6(self):
        sp = Setpoint(SetpointParams.thesis())
        self.assertAlmostEqual(sp.duration(), 0.19, delta=1e-12)
        a, b = sp.scan_window()
        self.assertAlmostEqual(a, 0.04, delta=1e-12)
        self.assertAlmostEqual(b, 0.17, delta=1e-12)
        r, v, acc, _, _ = sp.evaluate(0.02)
        self.assertAlmostEqual(r, 0.01, delta=1e-12)
        self.assertAlmostEqual(v, 1.0, delta=1e-12)
        self.assertLess(abs(acc), 1e-9)
        self.assertAlmostEqual(sp.evaluate(0.04)[0], 0.03, delta=1e-12)
        self.assertAlmostEqual(sp.evaluate(0.17)[0], 0.16, delta=1e-12)
        end = sp.evaluate(0.19)
        self.assertAlmostEqual(end[0], 0.17, delta=1e-12)
        self.assertEqual(end[1:], (0.0, 0.0, 0.0, 0.0))
        self.assertAlmostEqual(sp.evaluate(0.01)[2], 100.0, delta=1e-9)
        self.assertAlmostEqual(sp.evaluate(0.005)[3], 2e4, delta=1e-6)
        self.assertEqual(sp.evaluate(0.001)[4], 4e6)
        self.assertEqual(sp.evaluate(0.012)[4], -4e6)
        self.assertEqual(sp.evaluate(-1.0), (0.0, 0.0, 0.0, 0.0, 0.0))
        for t in (-1.0, 0.003, 0.0501, 0.18, 0.3):
            self.assertEqual(sp.position(t), sp.evaluate(t)[0])
        bad = SetpointParams.thesis()
        bad.a_max = 50.0
        with self.assertRaisesRegex(SetpointError, "inconsistent"):
            Setpoint(bad)
        bad.a_max = float("nan")
        with self.assertRaises(SetpointError):
            Setpoint(bad)


class References(unittest.TestCase):
    """shared/design reference.rs's tests, and what a law asks of one."""

    def test_sine_derivatives_match_finite_differences(self):
        r = Reference("sine", amplitude=2.0, omega=3.0, start_s=0.0)
        h, t = 1e-6, 0.4
        for i in range(4):
            numeric = (r.derivatives(t + h)[i] - r.derivatives(t - h)[i]) / (2.0 * h)
            exact = r.derivatives(t)[i + 1]
            self.assertLess(abs(numeric - exact), 1e-4 * max(abs(exact), 1.0), i)

    def test_a_meander_scans_back_and_forth_continuously(self):
        r = Reference(
            "scan", setpoint=Setpoint(SetpointParams.thesis()), start_s=0.01, repeat_s=0.25
        )
        self.assertAlmostEqual(r.sample(0.01 + 0.2), 0.17, delta=1e-9)
        self.assertLess(abs(r.sample(0.01 + 0.25 + 0.2)), 1e-9)
        before, after = r.derivatives(0.01 + 0.25 - 1e-6), r.derivatives(0.01 + 0.25 + 1e-6)
        self.assertLess(abs(before[0] - after[0]), 1e-9)
        self.assertLessEqual(after[1], 0.0)
        self.assertIsNone(r.end_s())

    def test_a_step_switches_at_its_time(self):
        r = Reference("step", amplitude=1.0, start_s=0.5)
        self.assertEqual((r.sample(0.49), r.sample(0.5)), (0.0, 1.0))
        self.assertEqual(r.derivatives(0.5), (1.0, 0.0, 0.0, 0.0, 0.0))

    def test_every_shape_from_a_scenario_with_its_deadline_and_amplitude(self):
        s = _settings(
            "[loop]\ncommand_deadline_us = 40\n[reference]\nshape = \"scan\"\n"
            "start_s = 0.01\nrepeat_s = 0.3\namplitude = -0.085\n"
        )
        r = Setup(s).reference()
        # Half the thesis' stroke, backwards, starting τ_d later.
        self.assertEqual(r.start_s, 0.01 + 40.0 / 1e6)
        self.assertAlmostEqual(r.sample(r.start_s + 0.19), -0.085, delta=1e-12)
        self.assertAlmostEqual(r.sample(r.start_s + 0.3 + 0.19), 0.0, delta=1e-12)
        out = [0.0] * 5
        self.assertIs(r.derivatives(0.05, out), out)
        self.assertEqual(tuple(out), r.derivatives(0.05))
        # The switching instants resolve to the segment that starts there.
        self.assertAlmostEqual(r.derivatives(r.start_s)[4] / 4e6, -0.5, delta=1e-12)
        hold = Setup(_settings("")).reference()
        self.assertEqual(hold.derivatives(1.0), (0.0,) * 5)

    def test_bad_fields_are_refused_as_the_rust_scenario_refuses_them(self):
        for text, says in [
            ("[reference]\nshape = \"hold\"\namplitude = 1.0\n",
             "field `reference.amplitude`: does not apply to reference.shape `hold`"),
            ("[reference]\nshape = \"sine\"\namplitude = 20\n",
             "field `reference.amplitude`: must lie in [-10, 10] m (or rad), got 20"),
            ("[reference]\nshape = \"sine\"\nfrequency_hz = 6000\n",
             "field `reference.frequency_hz`: 6000 Hz is not below the Nyquist frequency 5000 Hz"),
            ("[reference]\nshape = \"scan\"\nstart_s = 0.01\nrepeat_s = 0.1\n",
             "field `reference.repeat_s`: a scan lasts 0.19 s; it cannot repeat every 0.1 s"),
            ("[reference]\nshape = \"step\"\ndirection = [0.0]\n",
             "field `reference.direction`: needs at least one non-zero entry"),
            ("[reference]\nshape = \"step\"\nstart_s = -1\n",
             "field `reference.start_s`: must lie in [0, 86400] s, got -1"),
            ("[reference]\nshape = \"step\"\nfrom = 1\n", "field `reference.from`: unknown field"),
            ("[reference]\nshape = \"step\"\namplitude = \"x\"\n",
             "field `reference.amplitude`: invalid type"),
        ]:
            with self.subTest(says=says), self.assertRaises(flexloop.ScenarioError) as caught:
                _settings(text)
            self.assertIn(says, str(caught.exception))
            self.assertTrue(str(caught.exception).startswith("scenario "))


class Commands(unittest.TestCase):
    def setUp(self):
        self.m = msg.Measurement(seq=5, n_inputs=1, n_outputs=2)
        self.m.y[0], self.m.y[1] = 0.25, -0.5
        self.c = msg.Command()
        self.out = [0.0] * 8
        self.law_r = [1.0, 2.0] + [0.0] * 6
        self.offset = [0.0] * 8

    def _command(self, result, n=1):
        p = CommandParts()
        p.take(result, self.m, self.out, n, self.offset)
        p.write(self.c, self.out, self.m, n, self.law_r)
        c = self.c
        return c.u[0], c.u_fb[0], c.u_ff[0], c.u_d[0], c.r[0], c.r[1], c.e_meas[0], c.e_meas[1]

    def test_a_plain_command_is_all_feedback(self):
        self.assertEqual(self._command(3.0), (3.0, 3.0, 0.0, 0.0, 1.0, 2.0, 0.75, 2.5))
        self.assertEqual(self._command([4.0])[:4], (4.0, 4.0, 0.0, 0.0))
        self.assertEqual(self._command(2)[:2], (2.0, 2.0))

    def test_an_output_says_its_parts(self):
        o = flexloop.Output(u_fb=1.0, u_ff=0.5, u_d=-0.25, r=0.125)
        self.assertEqual(self._command(o), (1.25, 1.0, 0.5, -0.25, 0.125, 0.0, -0.125, 0.5))
        o = flexloop.Output(u=9.0, u_ff=2.0, r=[1.0, 3.0], e_meas=[7.0, 8.0])
        self.assertEqual(self._command(o), (9.0, 0.0, 2.0, 0.0, 1.0, 3.0, 7.0, 8.0))
        # u alone: all of it feedback, as a plain one.
        self.assertEqual(self._command(flexloop.Output(u=5.0))[:4], (5.0, 5.0, 0.0, 0.0))

    def test_a_default_shift_moves_u_and_its_feedback_part(self):
        self.offset[0] = 0.5
        o = flexloop.Output(u_fb=1.0, u_ff=2.0)
        self.assertEqual(self._command(o)[:4], (3.5, 1.5, 2.0, 0.0))
        self.assertEqual(self._command(1.0)[:2], (1.5, 1.5))

    def test_what_is_no_command_is_refused(self):
        for bad, n in [
            (flexloop.Output(), 1),
            (flexloop.Output(u=1.0), 2),
            (flexloop.Output(u=[1.0]), 2),
            ("1", 1),
            (None, 1),
            ([1.0], 2),
        ]:
            with self.subTest(bad=bad), self.assertRaises((TypeError, IndexError, ValueError)):
                CommandParts().take(bad, self.m, self.out, n, self.offset)


class Estimates(unittest.TestCase):
    def test_what_a_law_returns_is_stamped_and_the_rest_zero(self):
        m = msg.Measurement(seq=41, tick_ns=7, published_ns=9, n_inputs=1, n_outputs=1)
        e = msg.Estimate()
        e.direct[3] = 5.0
        write_estimate([1.0, 2.0], e, m)
        self.assertEqual((e.seq, e.n_states, e.x_hat[0], e.x_hat[1]), (42, 2, 1.0, 2.0))
        self.assertEqual((e.source_tick_ns, e.source_published_ns, e.direct[3]), (7, 9, 0.0))
        write_estimate(([3.0], 0.5), e, m)
        self.assertEqual((e.n_states, e.x_hat[0], e.innovation[0]), (1, 3.0, 0.5))
        write_estimate(
            flexloop.Estimated(x_hat=(1.0, 2.0), innovation=[0.25], free=[1.0], direct=[2.0]),
            e,
            None,
            3,
            2,
        )
        self.assertEqual((e.seq, e.n_outputs, e.n_inputs, e.free[0], e.direct[0]), (0, 3, 2, 1.0, 2.0))
        # Two states returned as a tuple are x̂, not (x̂, innovation).
        write_estimate((4.0, 5.0), e, m)
        self.assertEqual((e.n_states, e.x_hat[1], e.innovation[0]), (2, 5.0, 0.0))
        for bad in (None, 1.0, "ab", [0.0] * 129, ["x"]):
            with self.subTest(bad=bad), self.assertRaises((TypeError, ValueError)):
                write_estimate(bad, e, m)


class ParamsRecord(unittest.TestCase):
    def test_the_record_lists_what_the_law_uses_and_what_it_defaulted(self):
        p = Params("s.toml", {"kp": 2, "mode": "fast"}, "observer")
        self.assertEqual(p.number("kp"), 2.0)
        self.assertEqual(p.number("ki", default=0.5), 0.5)
        self.assertEqual(p.text("mode", default="slow", choices=("fast", "slow")), "fast")
        self.assertEqual(p.integer("n", default=3), 3)
        self.assertEqual(p.flag("on", default=False), False)
        self.assertEqual(p.numbers("poles", default=[1, 2]), (1.0, 2.0))
        p.check_all_read()
        record = p.record(4)
        self.assertEqual(
            record,
            {
                "role": "observer",
                "generation": 4,
                "params": {"kp": 2.0, "ki": 0.5, "mode": "fast", "n": 3, "on": False,
                           "poles": [1.0, 2.0]},
                "defaulted": ["ki", "n", "on", "poles"],
            },
        )
        run_dir = tempfile.mkdtemp()
        path = write_params_record(run_dir, p, 4)
        self.assertEqual(path, os.path.join(run_dir, "params", "observer.g4.json"))
        self.assertEqual(json.loads(pathlib.Path(path).read_text()), record)
        self.assertEqual(os.listdir(os.path.join(run_dir, "params")), ["observer.g4.json"])
        self.assertEqual(
            params_record_path(run_dir, "controller", 0),
            os.path.join(run_dir, "params", "controller.json"),
        )

    def test_bad_values_name_the_field(self):
        p = Params("s.toml", {"n": 1.5, "mode": "x", "v": [1, "a"]})
        with self.assertRaisesRegex(flexloop.ScenarioError, "`controller.params.n`: must be an integer"):
            p.integer("n")
        with self.assertRaisesRegex(flexloop.ScenarioError, "`controller.params.mode`: unknown `x`"):
            p.text("mode", choices=("a", "b"))
        with self.assertRaisesRegex(flexloop.ScenarioError, "`controller.params.v`: must be a list"):
            p.numbers("v")
        with self.assertRaisesRegex(flexloop.ScenarioError, "`controller.params.k`: missing"):
            p.flag("k")


class CatchUp(unittest.TestCase):
    """shared/node replay.rs's tests of ``CatchUp``."""

    def _m(self, seq):
        return msg.Measurement(seq=seq)

    def test_replay_and_live_merge_into_one_gapless_sequence(self):
        c = _CatchUp(9, [msg.Measurement() for _ in range(STASH)])
        stepped = []
        arrivals = [("l", 14), ("r", 10), ("l", 15), ("r", 11), ("r", 12), ("l", 16), ("r", 13),
                    ("r", 14)]
        for kind, seq in arrivals:
            if kind == "r":
                if c.replayed(self._m(seq)) == _CatchUp.STEP:
                    stepped.append(seq)
            else:
                c.hold_live(self._m(seq))
            if c.reached_live():
                while (h := c.take_held()) is not None:
                    stepped.append(h.seq)
                break
        self.assertEqual(stepped, list(range(10, 17)))

    def test_older_replayed_samples_are_skipped_and_a_hole_is_a_gap(self):
        c = _CatchUp(9, [msg.Measurement() for _ in range(STASH)])
        self.assertEqual(c.replayed(self._m(8)), _CatchUp.SKIP)
        self.assertEqual(c.replayed(self._m(10)), _CatchUp.STEP)
        self.assertEqual(c.replayed(self._m(12)), _CatchUp.GAP)
        self.assertEqual(c.next, 11)
        c.hold_live(self._m(13))
        self.assertFalse(c.reached_live())
        for seq in (11, 12):
            c.hold_live(self._m(seq))
        self.assertFalse(c.reached_live(), "held out of order: 13 first")

    def test_a_restart_without_a_continuous_state_flags_its_next_settling_samples_estimates(self):
        class Quick(flexloop.Observer):
            def step(self, measurement):
                return [0.0]

            def settling_samples(self):
                return 3

        said = []

        class Program:
            def say(self, line):
                said.append(line)

        class Settings:
            n_outputs, n_inputs = 1, 1

        # The runner's bookkeeping of one estimate after another, without ports.
        p = _Process.__new__(_Process)
        p.law, p.program, p.settings = Quick.__new__(Quick), Program(), Settings()
        p.generation, p.stepped, p.first_stepped = 1, 0, None
        p.converging_until, p.converging_for = None, None
        e = msg.Estimate()

        def flags_of(seqs):
            out = []
            for seq in seqs:
                p._step(self._m(seq), e)
                out.append(bool(e.flags & msg.Flags.CONVERGING))
            return out

        self.assertEqual(flags_of([10, 11]), [False, False])
        p._start_converging()
        # The estimates for ticks 13, 14 and 15, then no more (the one
        # estimate, reused, has its bit cleared again).
        self.assertEqual(flags_of([12, 13, 14, 15, 16]), [True, True, True, False, False])
        self.assertTrue(any("converging" in line for line in said), said)


class Examples(unittest.TestCase):
    def test_the_luenberger_example_is_the_rust_examples_predictor(self):
        s = Setup(_settings("[observer.params]\nmass_kg = 2.0\nbandwidth_hz = 150.0\n"
                            "damping = 0.6\n", "observer"))
        law = _example("luenberger").Predictor(s)
        s.params.check_all_read()
        self.assertEqual(list(law.initial()), [0.0, 0.0])
        ts, w, z = 1e-4, 2.0 * math.pi * 150.0, 0.6
        decay = math.exp(-z * w * ts)
        l1 = -2.0 * decay * math.cos(w * ts * math.sqrt(1.0 - z * z)) + 2.0
        l2 = (decay * decay - 1.0 + l1) / ts
        x = [0.0, 0.0]
        m = msg.Measurement(n_inputs=1, n_outputs=1)
        for k in range(50):
            m.seq, m.y[0], m.u_applied[0] = k, 1e-3 * math.sin(k * 0.01), 0.1 * k
            out = law.step(m)
            inn = m.y[0] - x[0]
            x = [x[0] + ts * x[1] + ts * ts / 4.0 * m.u_applied[0] + l1 * inn,
                 x[1] + ts / 2.0 * m.u_applied[0] + l2 * inn]
            self.assertEqual(list(out.x_hat), x)
            self.assertEqual(out.innovation[0], inn)
        state = list(law.save_state())
        other = _example("luenberger").Predictor(s)
        other.load_state(state)
        self.assertEqual(list(other.initial()), x)

    def test_the_luenberger_example_refuses_a_loop_it_does_not_fit(self):
        s = Setup(_settings("[plant]\nmodel = \"mimo-example\"\n[observer.params]\n"
                            "mass_kg = 1.0\nbandwidth_hz = 150.0\ndamping = 0.6\n", "observer"))
        with self.assertRaisesRegex(flexloop.SetupError, "one input and one output"):
            _example("luenberger").Predictor(s)
        s = Setup(_settings("[observer.params]\nmass_kg = 1.0\nbandwidth_hz = 150.0\n"
                            "damping = 1.0\n", "observer"))
        with self.assertRaisesRegex(flexloop.SetupError, "damping in"):
            _example("luenberger").Predictor(s)


if __name__ == "__main__":
    unittest.main()
