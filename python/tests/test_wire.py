"""The Python messages and channels against shared/protocol's own tables.

wire.json is shared/protocol's description of itself (shared/protocol
wire.rs makes it from the structs and layout tables; its test fails when
the copy here is stale). These tests fail when a ctypes structure drifts
from it: a field renamed, moved, resized or missing, a type name or size
that iceoryx2 would refuse.
"""

import ctypes
import pathlib
import re
import unittest
from importlib import metadata

from flexloop import messages, transport

_SCALARS = {"u64": ctypes.c_uint64, "u32": ctypes.c_uint32, "f64": ctypes.c_double}
_REPO = pathlib.Path(__file__).resolve().parents[2]


class MessagesMatchTheProtocol(unittest.TestCase):
    def setUp(self):
        self.wire = messages.wire_description()

    def test_every_message_has_its_type_name_size_and_alignment(self):
        messages.check_against_wire(self.wire)
        self.assertEqual(
            sorted(m["name"] for m in self.wire["messages"]), sorted(messages.MESSAGES)
        )

    def test_every_field_has_its_name_offset_type_and_length(self):
        for m in self.wire["messages"]:
            cls = messages.MESSAGES[m["name"]]
            ours = cls._fields_
            with self.subTest(message=m["name"]):
                self.assertEqual(
                    [f[0] for f in ours], [f["name"] for f in m["fields"]], "field names in order"
                )
                for (name, ctype), f in zip(ours, m["fields"]):
                    self.assertEqual(getattr(cls, name).offset, f["offset"], name)
                    self.assertEqual(ctypes.sizeof(ctype), f["size"], name)
                    scalar = _SCALARS[f["scalar"]]
                    if f["len"] == 0:
                        self.assertIs(ctype, scalar, name)
                    else:
                        self.assertIs(ctype._type_, scalar, name)
                        self.assertEqual(ctype._length_, f["len"], name)

    def test_constants_and_flags_match(self):
        for name, value in self.wire["constants"].items():
            self.assertEqual(getattr(messages, name), value, name)
        for name, value in self.wire["flags"].items():
            self.assertEqual(getattr(messages.Flags, name), value, name)
        for name, value in self.wire["handover_marks"].items():
            self.assertEqual(getattr(messages.HandoverMark, name), value, name)

    def test_a_drifted_message_is_refused_by_name(self):
        wire = messages.wire_description()
        wire["messages"][0]["size"] += 8
        with self.assertRaisesRegex(messages.WireMismatch, "Measurement"):
            messages.check_against_wire(wire)

    def test_the_channels_the_controller_opens_are_the_protocols(self):
        names = {c["name"] for c in self.wire["channels"]}
        for name in (
            "flexloop/measurement",
            "flexloop/estimate",
            "flexloop/command",
            "flexloop/controller-state",
            "flexloop/activation",
        ):
            self.assertIn(name, names)
            self.assertIs(transport.channel(name), transport.CHANNELS[name])


class Iceoryx2IsPinnedWithTheRustCrate(unittest.TestCase):
    def test_the_installed_iceoryx2_is_cargo_locks(self):
        lock = (_REPO / "Cargo.lock").read_text()
        rust = re.search(r'name = "iceoryx2"\nversion = "([^"]+)"', lock).group(1)
        self.assertEqual(metadata.version("iceoryx2"), rust)
        pyproject = (_REPO / "python" / "pyproject.toml").read_text()
        self.assertIn(f'"iceoryx2=={rust}"', pyproject)


if __name__ == "__main__":
    unittest.main()
