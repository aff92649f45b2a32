//! Bad input: a clear error naming the file and the field, nothing started.

use crate::util::*;
use std::time::Duration;

fn up_with(scenario_path: &std::path::Path, run_dir: &std::path::Path) -> std::process::Output {
    let mut cmd = flexloop();
    cmd.arg("up")
        .arg(scenario_path)
        .args(["--no-realtime", "--duration", "0.1", "--run-dir"])
        .arg(run_dir);
    run_bounded(cmd, Duration::from_secs(30))
}

fn write_variant(dir: &std::path::Path, from: &str, to: &str) -> std::path::PathBuf {
    let lecture = "lecture-double-integrator";
    scenario_variant(dir, lecture, "bad.toml", &[(from, to)], "")
}

#[test]
fn unknown_field_names_file_and_field() {
    let dir = temp_dir("bad-field");
    let path = write_variant(&dir, "mass_kg = 1.0", "mass_kilograms = 1.0");
    let out = up_with(&path, &dir.join("run"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains("bad.toml") && err.contains("mass_kilograms"),
        "{err}"
    );
    assert!(processes_mentioning(&dir.display().to_string()).is_empty());
}

#[test]
fn invalid_value_names_the_field() {
    let dir = temp_dir("bad-value");
    let path = write_variant(
        &dir,
        "observer_bandwidth_hz = 200.0",
        "observer_bandwidth_hz = 9000.0",
    );
    let out = up_with(&path, &dir.join("run"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains("observer.observer_bandwidth_hz") && err.contains("Nyquist"),
        "{err}"
    );
}

#[test]
fn missing_scenario_file_is_reported() {
    let dir = temp_dir("missing");
    let out = up_with(&dir.join("nope.toml"), &dir.join("run"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        err.contains("nope.toml") && err.contains("cannot read"),
        "{err}"
    );
}

#[test]
fn unwritable_run_directory_is_reported_before_anything_starts() {
    let dir = temp_dir("unwritable");
    let out = up_with(
        &scenario("lecture-double-integrator"),
        std::path::Path::new("/proc/flexloop-run"),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(err.contains("/proc/flexloop-run"), "{err}");
    assert!(processes_mentioning("/proc/flexloop-run").is_empty());
    let _ = dir;
}

#[test]
fn supervision_settings_are_checked() {
    let dir = temp_dir("bad-supervision");
    for (section, field) in [
        (
            "command_watchdog_ticks = 0",
            "supervision.command_watchdog_ticks",
        ),
        ("safe_action = \"explode\"", "safe_action"),
    ] {
        let table = format!("[supervision]\n{section}");
        let path = scenario_variant(&dir, "lecture-double-integrator", "bad.toml", &[], &table);
        let out = up_with(&path, &dir.join("run"));
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
        assert!(err.contains("bad.toml") && err.contains(field), "{err}");
    }
    assert!(processes_mentioning(&dir.display().to_string()).is_empty());
}

#[test]
fn a_swap_into_another_plant_is_refused_and_the_loop_runs_on() {
    let dir = temp_dir("bad-swap");
    let (child, prefix) = start(&dir, "lecture-double-integrator", &["--rate", "1000"]);
    wait_for_ticks(&dir, 1);
    let mut swap = flexloop();
    swap.args(["swap", "controller"])
        .arg(scenario("thesis-original"))
        .args(["--prefix", &prefix]);
    let out = run_bounded(swap, Duration::from_secs(60));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains("thesis-original.toml") && err.contains("plant"),
        "{err}"
    );
    stop(&prefix, child);
    assert_clean(&dir);
}

/// A variant of the shipped scenario `name` with `from` replaced by `to`.
fn variant_of(dir: &std::path::Path, name: &str, from: &str, to: &str) -> std::path::PathBuf {
    scenario_variant(dir, name, &format!("bad-{name}.toml"), &[(from, to)], "")
}

/// `flexloop up` refuses the file with exit status 2 and a message naming the
/// file, the field and every fragment of the reason; nothing starts.
fn refused(dir: &std::path::Path, path: &std::path::Path, field: &str, reason: &[&str]) {
    let out = up_with(path, &dir.join("run"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    let file = path.file_name().unwrap().to_string_lossy();
    assert!(
        err.contains(file.as_ref()) && err.contains(field),
        "{field}: {err}"
    );
    for r in reason {
        assert!(err.contains(r), "{field}: no `{r}` in {err}");
    }
    assert!(processes_mentioning(&dir.display().to_string()).is_empty());
    assert!(
        !dir.join("run")
            .join(flexloop_runfiles::RunDir::SAMPLES)
            .exists()
    );
}

#[test]
fn mimo_settings_on_a_siso_plant_are_refused_before_anything_starts() {
    let dir = temp_dir("bad-mimo-on-siso");
    // A reference direction for two outputs on the one-output thesis chain.
    let path = variant_of(
        &dir,
        "thesis-original",
        "shape = \"scan\"",
        "shape = \"scan\"\ndirection = [1.0, 0.0]",
    );
    refused(
        &dir,
        &path,
        "reference.direction",
        &["2 entries", "1 output"],
    );
    // Encoder selection belongs to the OAT-like model.
    let path = variant_of(
        &dir,
        "lecture-double-integrator",
        "mass_kg = 1.0",
        "mass_kg = 1.0\nencoders = [1, 2, 4]",
    );
    refused(&dir, &path, "plant.encoders", &["OAT"]);
    // The MIMO models measure every sensor: one `output` is a mistake.
    let path = variant_of(
        &dir,
        "mimo-example",
        "input_limit",
        "output = 1\ninput_limit",
    );
    refused(&dir, &path, "plant.output", &["reference.direction"]);
}

#[test]
fn an_observer_model_larger_than_the_plant_is_refused() {
    let dir = temp_dir("bad-observer-model");
    // The two-inertia setup has one flexible mode; the observer cannot keep three.
    let path = variant_of(
        &dir,
        "two-inertia",
        "design = \"kalman\"",
        "design = \"kalman\"\nflexible_modes = 3",
    );
    refused(
        &dir,
        &path,
        "observer.flexible_modes",
        &["1 flexible mode", "3"],
    );
    // Nor can the MIMO example's observer keep four of its three.
    let path = variant_of(
        &dir,
        "mimo-example",
        "design = \"kalman\"",
        "design = \"kalman\"\nflexible_modes = 4",
    );
    refused(
        &dir,
        &path,
        "observer.flexible_modes",
        &["3 flexible modes"],
    );
}

#[test]
fn an_unstable_mimo_design_is_refused() {
    let dir = temp_dir("bad-unstable-mimo");
    let path = variant_of(
        &dir,
        "mimo-example",
        "bandwidth_hz = 37.0",
        "bandwidth_hz = 400.0",
    );
    refused(&dir, &path, "controller.bandwidth_hz", &["unstable"]);
    let path = variant_of(
        &dir,
        "oat-like",
        "bandwidth_hz = 26.0",
        "bandwidth_hz = 400.0",
    );
    refused(&dir, &path, "controller.bandwidth_hz", &["unstable"]);
}

#[test]
fn a_mimo_trajectory_beyond_an_actuator_is_refused() {
    let dir = temp_dir("bad-limit-mimo");
    let path = variant_of(
        &dir,
        "mimo-example",
        "input_limit = 2000.0",
        "input_limit = 100.0",
    );
    refused(&dir, &path, "plant.input_limit", &["on input", "100 N"]);
    let path = variant_of(
        &dir,
        "two-inertia",
        "input_limit = 1.0",
        "input_limit = 0.001",
    );
    refused(&dir, &path, "plant.input_limit", &["0.001 A"]);
}

/// `flexloop design` accepts exactly what `flexloop up` accepts: the files
/// design printed a report for and up refused, and a name that would have
/// put the run outside runs/, are refused by both with the same message.
#[test]
fn design_and_up_refuse_the_same_files_with_the_same_message() {
    let dir = temp_dir("design-up");
    for (from, to, field) in [
        (
            "design = \"kalman\"",
            "design = \"magic\"",
            "observer.design",
        ),
        ("shape = \"scan\"", "shape = \"square\"", "reference.shape"),
        (
            "bandwidth_hz = 43.5",
            "bandwidth_hz = 4999",
            "controller.bandwidth_hz",
        ),
        (
            "name = \"default\"",
            "name = \"x/../../../escaped\"",
            "name",
        ),
    ] {
        let path = variant_of(&dir, "default", from, to);
        let mut design = flexloop();
        design.arg("design").arg(&path);
        let design = run_bounded(design, Duration::from_secs(60));
        // Without --run-dir: the name would choose the directory.
        let mut up = flexloop();
        up.arg("up")
            .arg(&path)
            .args(["--no-realtime", "--duration", "0.1"]);
        let up = run_bounded(up, Duration::from_secs(60));
        for out in [&design, &up] {
            assert_eq!(out.status.code(), Some(2), "{field}: {}", describe(out));
        }
        let (design_err, up_err) = (
            String::from_utf8_lossy(&design.stderr),
            String::from_utf8_lossy(&up.stderr),
        );
        assert_eq!(design_err, up_err);
        assert!(
            design_err.contains("bad-default.toml") && design_err.contains(field),
            "{field}: {design_err}"
        );
    }
    // runs/<stamp>-x/../../../escaped-<pid> is beside the checkout.
    let beside = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let escaped: Vec<_> = std::fs::read_dir(beside)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("escaped-"))
        .map(|e| e.path())
        .collect();
    assert!(escaped.is_empty(), "{escaped:?}");
}

/// `thesis-original` with its plant replaced by `plant`, in `dir`.
fn own_plant_variant(dir: &std::path::Path, plant: &str) -> std::path::PathBuf {
    scenario_variant(
        dir,
        "thesis-original",
        "bad-own.toml",
        &[("model = \"thesis-chain\"\noutput = 5\n", plant)],
        "",
    )
}

/// `flexloop up` and `flexloop design` refuse the scenario alike, naming
/// the scenario, the field and every fragment; nothing starts or remains.
fn both_refuse(dir: &std::path::Path, path: &std::path::Path, field: &str, reason: &[&str]) {
    refused(dir, path, field, reason);
    let mut design = flexloop();
    design.arg("design").arg(path);
    let out = run_bounded(design, Duration::from_secs(60));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(err.contains("bad-own.toml") && err.contains(field), "{err}");
    for r in reason {
        assert!(err.contains(r), "design: no `{r}` in {err}");
    }
    assert!(processes_mentioning(&dir.display().to_string()).is_empty());
}

#[test]
fn a_matlab_v7_3_model_file_is_refused_with_the_advice_to_save_with_v7() {
    let dir = temp_dir("bad-mat-v73");
    // MATLAB's v7.3 is HDF5: the 128-byte text header, the HDF5 signature
    // at byte 512.
    let mut v73 =
        b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan 13 2025 HDF5 schema 1.00 ."
            .to_vec();
    v73.resize(116, b' ');
    v73.extend_from_slice(&[0; 8]);
    v73.extend_from_slice(&[0x00, 0x02, b'I', b'M']);
    v73.resize(512, 0);
    v73.extend_from_slice(b"\x89HDF\r\n\x1a\n");
    v73.resize(4096, 0);
    std::fs::write(dir.join("plant.mat"), &v73).unwrap();
    let path = own_plant_variant(&dir, "model = \"state-space\"\nfile = \"plant.mat\"\n");
    both_refuse(&dir, &path, "plant.file", &["plant.mat", "v7.3", "-v7"]);
}

#[test]
fn a_numpy_model_with_a_non_symmetric_k_is_refused_naming_the_file_and_k() {
    let dir = temp_dir("bad-npz-k");
    let mut cmd = std::process::Command::new(python_with(&["numpy"]));
    cmd.arg("-c")
        .arg(
            "import sys, numpy as np\n\
             np.savez(sys.argv[1], M=np.diag([2.5, 10.0]), \
             K=np.array([[1e8, -1e8], [-0.9e8, 1e8]]), B=np.array([1.0, 0.0]), \
             C=np.array([0.0, 1.0]))",
        )
        .arg(dir.join("plant.npz"));
    let out = run_bounded(cmd, Duration::from_secs(60));
    assert!(out.status.success(), "{}", describe(&out));
    let path = own_plant_variant(
        &dir,
        "model = \"second-order\"\nfile = \"plant.npz\"\nzeta = 0.01\n",
    );
    both_refuse(
        &dir,
        &path,
        "plant.file",
        &["plant.npz", "K: is not symmetric"],
    );
}

/// Writes the hostile model files (docs/own-plant.md) into the directory given as
/// its argument, with NumPy and the standard library only (the archives and
/// MAT-files byte by byte where a writer would refuse or take minutes).
const WRITE_HOSTILE_FILES: &str = r#"
import struct, sys, zlib, pathlib
import numpy as np

out = pathlib.Path(sys.argv[1])

def bomb(prefix, total, wbits):
    # One 1 MiB block of zeros compressed after the prefix, then repeated:
    # each copy refers back only to zeros, so all inflate alike.
    c = zlib.compressobj(9, zlib.DEFLATED, wbits)
    zeros = bytes(1 << 20)
    stream = c.compress(prefix + zeros) + c.flush(zlib.Z_SYNC_FLUSH)
    block = c.compress(zeros) + c.flush(zlib.Z_SYNC_FLUSH)
    copies = -(-(total - len(prefix) - len(zeros)) // len(zeros))
    return stream + block * copies + c.flush(zlib.Z_FINISH)

def npy_header(shape):
    d = "{'descr': '<f8', 'fortran_order': False, 'shape': %s, }" % (shape,)
    d += " " * ((-(10 + len(d) + 1)) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(d)) + d.encode()

def zip_one(name, data, method, declared, crc=0):
    n = name.encode()
    local = struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, method, 0, 0x21, crc,
                        len(data), declared, len(n), 0) + n + data
    central = struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 20, 20, 0, method, 0, 0x21,
                          crc, len(data), declared, len(n), 0, 0, 0, 0, 0, 0) + n
    end = struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, 1, 1, len(central), len(local), 0)
    return local + central + end

# A 2 MB member inflating to 2 GiB, declaring it (np.savez_compressed
# would) and declaring 1 KiB.
m = bomb(npy_header("(2, 2)"), 2 << 30, -15)
(out / "bomb.npz").write_bytes(zip_one("M.npy", m, 8, 2 << 30))
(out / "bomb-lying.npz").write_bytes(zip_one("M.npy", m, 8, 1024))
# A stored .npy whose header declares 100000 x 100000 and holds four numbers.
k = npy_header("(100000, 100000)") + np.ones(4).tobytes()
(out / "shape.npz").write_bytes(zip_one("K.npy", k, 0, len(k), zlib.crc32(k)))

def mat_header():
    text = b"MATLAB 5.0 MAT-file Platform: posix, Created by: flexloop tests"
    return text.ljust(116, b" ") + bytes(8) + b"\x00\x01IM"

def tag(t, n):
    return struct.pack("<II", t, n)

def pad(b):
    return b + bytes(-len(b) % 8)

def mat_double(name, dims, data, declared=None, data_len=None):
    e = tag(6, 8) + bytes([6, 0, 0, 0, 0, 0, 0, 0])
    e += pad(tag(5, 4 * len(dims)) + struct.pack("<%di" % len(dims), *dims))
    e += pad(tag(1, len(name)) + name.encode())
    e += pad(tag(9, len(data) if data_len is None else data_len) + data)
    return tag(14, len(e) if declared is None else declared) + e

# Uncompressed: K declares 100000 x 100000 and holds four numbers.
(out / "dims.mat").write_bytes(mat_header() + mat_double("K", [100000, 100000], np.ones(4).tobytes()))
# Compressed: M, 2 x 2, whose data inflate to 1 GiB from 1 MB.
head = mat_double("M", [2, 2], b"", (1 << 30) + 64, 1 << 30)
z = bomb(head, 1 << 30, 15)
(out / "bomb.mat").write_bytes(mat_header() + tag(15, len(z)) + z)
# M's name declared 17 bytes long: matrw 0.1.4 panics on it (caught).
m = bytearray(mat_double("M", [2, 2], np.eye(2).tobytes()))
name_tag = 8 + 16 + 16  # after the element's tag, the array flags, the dimensions
m[name_tag + 4:name_tag + 8] = struct.pack("<I", 17)
b = mat_double("B", [2, 1], np.array([1.0, 0.0]).tobytes())
(out / "panic.mat").write_bytes(mat_header() + bytes(m) + b)

def chain(n):
    k = np.zeros((n, n))
    for i in range(n - 1):
        k[i:i + 2, i:i + 2] += 1e6 * np.array([[1.0, -1.0], [-1.0, 1.0]])
    return k

for n in (65, 1000):
    b = np.zeros(n); b[0] = 1.0
    c = np.zeros(n); c[-1] = 1.0
    np.savez(out / ("dof%d.npz" % n), M=np.eye(n), K=chain(n), B=b, C=c)
n = 129
np.savez(out / "states129.npz", A=-np.eye(n), B=np.ones(n), C=np.ones(n))
"#;

/// The exit status, wall time and peak resident size of a child, reaped
/// with wait4 so that the figures are its own (the tests' other children
/// run beside it).
struct Measured {
    out: std::process::Output,
    wall: Duration,
    peak_rss_bytes: u64,
}

/// Runs `cmd` to its end (killed after `limit`, then panicking), measured.
fn run_measured(mut cmd: std::process::Command, limit: Duration) -> Measured {
    use std::io::Read;
    use std::os::unix::process::ExitStatusExt;
    let since = std::time::Instant::now();
    // Reaped by wait4 below, which gives its resource usage; std's wait does not.
    #[allow(clippy::zombie_processes)]
    let mut child = cmd
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let drain = |pipe: Option<Box<dyn Read + Send>>| {
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            if let Some(mut pipe) = pipe {
                let _ = pipe.read_to_end(&mut bytes);
            }
            bytes
        })
    };
    let stdout = drain(child.stdout.take().map(|p| Box::new(p) as _));
    let stderr = drain(child.stderr.take().map(|p| Box::new(p) as _));
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: a zeroed rusage is valid; wait4 fills it and the status for
    // our own child, which nothing else waits for.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let mut timed_out = false;
    loop {
        let flags = if timed_out { 0 } else { libc::WNOHANG };
        // SAFETY: as above.
        let reaped = unsafe { libc::wait4(pid, &mut status, flags, &mut usage) };
        if reaped == pid {
            break;
        }
        assert_eq!(reaped, 0, "wait4: {}", std::io::Error::last_os_error());
        if since.elapsed() > limit {
            // SAFETY: our child, not reaped yet, so the pid is not reused.
            unsafe { libc::kill(pid, libc::SIGKILL) };
            timed_out = true;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let wall = since.elapsed();
    let out = std::process::Output {
        status: std::process::ExitStatus::from_raw(status),
        stdout: stdout.join().unwrap(),
        stderr: stderr.join().unwrap(),
    };
    assert!(!timed_out, "timed out after {limit:?}\n{}", describe(&out));
    Measured {
        out,
        wall,
        // Linux gives ru_maxrss in KiB.
        peak_rss_bytes: u64::try_from(usage.ru_maxrss).unwrap() * 1024,
    }
}

/// `thesis-original` with its plant replaced by `plant`, as `dir/file`.
fn plant_variant(dir: &std::path::Path, file: &str, plant: &str) -> std::path::PathBuf {
    scenario_variant(
        dir,
        "thesis-original",
        file,
        &[("model = \"thesis-chain\"\noutput = 5\n", plant)],
        "",
    )
}

/// `flexloop design` refuses `scenario` at once: exit status 2, one line
/// naming the scenario, `field` and every fragment of `reason`, nothing
/// else on stderr (no panic message, with RUST_BACKTRACE set), within the
/// bounds; what it took, for the report.
fn design_refuses_at_once(scenario: &std::path::Path, field: &str, reason: &[&str]) -> Measured {
    let mut design = flexloop();
    design
        .arg("design")
        .arg(scenario)
        .env("RUST_BACKTRACE", "1");
    // 30 s: a bound against a hang, not a timing claim (each takes
    // milliseconds; before the limits: 13.5 s, 226 s and forever).
    let m = run_measured(design, Duration::from_secs(30));
    let err = String::from_utf8_lossy(&m.out.stderr);
    assert_eq!(m.out.status.code(), Some(2), "{}", describe(&m.out));
    assert_eq!(err.lines().count(), 1, "{err}");
    let name = scenario.file_name().unwrap().to_string_lossy();
    assert!(
        err.contains(name.as_ref()) && err.contains(&format!("field `{field}`")),
        "{field}: {err}"
    );
    for r in reason {
        assert!(err.contains(r), "no `{r}` in {err}");
    }
    assert!(
        m.peak_rss_bytes < 200 << 20,
        "{name}: peak resident size {} MiB",
        m.peak_rss_bytes >> 20
    );
    println!(
        "{name}: refused in {:.3} s, peak resident size {:.1} MiB",
        m.wall.as_secs_f64(),
        m.peak_rss_bytes as f64 / f64::from(1 << 20)
    );
    m
}

/// Model files that exhausted the machine (a FIFO blocked
/// `design` forever, /dev/zero and zip bombs took gigabytes, a 1000-mass
/// model minutes) are refused at once, each naming the file, the array and
/// the reason, in bounded memory.
#[test]
fn hostile_model_files_are_refused_at_once_naming_the_file_and_the_array() {
    let dir = temp_dir("hostile-model-files");
    let mut python = std::process::Command::new(python_with(&["numpy"]));
    python.arg("-c").arg(WRITE_HOSTILE_FILES).arg(&*dir);
    let out = run_bounded(python, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    let made = std::process::Command::new("mkfifo")
        .arg(dir.join("fifo.npz"))
        .status()
        .unwrap();
    assert!(made.success());
    std::os::unix::fs::symlink("/dev/zero", dir.join("zero.npz")).unwrap();
    std::fs::create_dir(dir.join("directory.mat")).unwrap();
    // Sparse: its size without the disk space.
    std::fs::File::create(dir.join("huge.mat"))
        .unwrap()
        .set_len(4 << 30)
        .unwrap();
    let state_space = "model = \"state-space\"\n";
    let second_order = "model = \"second-order\"\nzeta = 0.01\n";
    let cases: [(&str, &str, &[&str]); 15] = [
        (
            "fifo.npz",
            state_space,
            &["is a FIFO (named pipe), not a regular file"],
        ),
        (
            "zero.npz",
            state_space,
            &["is a character device, not a regular file"],
        ),
        (
            "/dev/zero",
            state_space,
            &["/dev/zero: the file name has no extension"],
        ),
        (
            "directory.mat",
            state_space,
            &["is a directory, not a regular file"],
        ),
        (
            "huge.mat",
            state_space,
            &["the file has 4 GiB, more than the 16 MiB"],
        ),
        ("bomb.npz", state_space, &["array `M`: its data take 2 GiB"]),
        ("bomb-lying.npz", state_space, &["array `M`: "]),
        (
            "shape.npz",
            second_order,
            &["array `K`: declares 100000×100000 entries"],
        ),
        (
            "dims.mat",
            second_order,
            &["array `K`: declares 100000×100000 entries"],
        ),
        (
            "bomb.mat",
            second_order,
            &["array `M`: its data inflate to more than 1 MiB"],
        ),
        (
            "panic.mat",
            second_order,
            &["variable 1 of 2 cannot be read: its data are damaged"],
        ),
        (
            "dof65.npz",
            second_order,
            &["array `M` is 65×65: a model of 65 degrees of freedom (130 states)"],
        ),
        (
            "dof1000.npz",
            second_order,
            &["array `M`: declares 1000×1000 entries"],
        ),
        (
            "states129.npz",
            state_space,
            &["array `A`: declares 129×129 entries"],
        ),
        (
            "missing.npz",
            state_space,
            &["cannot read the file: No such file"],
        ),
    ];
    for (i, (file, model, reason)) in cases.into_iter().enumerate() {
        let plant = format!("{model}file = \"{file}\"\n");
        let name = format!("hostile-{i}-{}.toml", file.replace('/', "-"));
        let scenario = plant_variant(&dir, &name, &plant);
        let mut expected = vec![file];
        expected.extend_from_slice(reason);
        design_refuses_at_once(&scenario, "plant.file", &expected);
    }
    // `up` refuses the FIFO as `design` does, and nothing starts.
    let scenario = plant_variant(
        &dir,
        "hostile-fifo.toml",
        "model = \"state-space\"\nfile = \"fifo.npz\"\n",
    );
    refused(&dir, &scenario, "plant.file", &["is a FIFO"]);
}

/// A lumped network beyond what the loop carries is refused from the
/// scenario, before the network is assembled or designed.
#[test]
fn a_lumped_network_beyond_the_loop_is_refused_before_designing() {
    let dir = temp_dir("hostile-lumped");
    let lumped = |masses: usize, forces: usize| {
        let list =
            |n: usize, f: &dyn Fn(usize) -> String| (0..n).map(f).collect::<Vec<_>>().join(", ");
        format!(
            "model = \"lumped\"\nmasses_kg = [{}]\nsprings = [{}]\nzeta = 0.01\n\
             forces = [{}]\npositions = [{{ at = {} }}]\n",
            list(masses, &|_| "1.0".into()),
            list(masses - 1, &|i| format!(
                "{{ between = [{i}, {}], stiffness = 1e6 }}",
                i + 1
            )),
            list(forces, &|i| format!("{{ at = {i} }}")),
            masses - 1
        )
    };
    let scenario = plant_variant(&dir, "masses.toml", &lumped(1000, 1));
    design_refuses_at_once(
        &scenario,
        "plant.masses_kg",
        &["1 to 64 masses", "got 1000"],
    );
    let scenario = plant_variant(&dir, "forces.toml", &lumped(20, 9));
    design_refuses_at_once(
        &scenario,
        "plant.forces",
        &["9 entries, each one of the loop's inputs: it carries at most 8"],
    );
    // The built-in chain's own bound.
    let scenario = scenario_variant(
        &dir,
        "uniform-chain",
        "nodes.toml",
        &[("nodes = 32", "nodes = 1000")],
        "",
    );
    design_refuses_at_once(&scenario, "plant.nodes", &["2..=64", "got 1000"]);
}

/// Ctrl-C (SIGINT) and SIGTERM end a long design at once (the largest
/// accepted uniform chain takes minutes in a debug build): `design`
/// installs no handler, so the default action ends it and the shell sees
/// the signal (exit status 130 or 143).
#[test]
fn a_signal_ends_a_long_design_at_once() {
    use std::os::unix::process::{CommandExt, ExitStatusExt};
    let dir = temp_dir("design-signal");
    let scenario = scenario_variant(
        &dir,
        "uniform-chain",
        "large.toml",
        &[("nodes = 32", "nodes = 64")],
        "",
    );
    for signal in [libc::SIGINT, libc::SIGTERM] {
        let mut design = flexloop();
        design.arg("design").arg(&scenario);
        // A test runner started in the background of a non-interactive
        // shell ignores SIGINT, and its children would inherit that: the
        // default action, as a terminal's Ctrl-C finds it.
        // SAFETY: signal() is async-signal-safe, as pre_exec requires.
        unsafe {
            design.pre_exec(|| {
                libc::signal(libc::SIGINT, libc::SIG_DFL);
                libc::signal(libc::SIGTERM, libc::SIG_DFL);
                Ok(())
            });
        }
        let mut child = design
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(1500));
        assert!(
            child.try_wait().unwrap().is_none(),
            "the design ended before the signal: {:?}",
            child.wait_with_output()
        );
        let sent = std::time::Instant::now();
        // SAFETY: our own child, not reaped yet, so the pid is not reused.
        unsafe { libc::kill(child.id() as i32, signal) };
        let out = wait_bounded(child, Duration::from_secs(10));
        println!(
            "design ended {:.3} s after signal {signal}",
            sent.elapsed().as_secs_f64()
        );
        assert_eq!(out.status.signal(), Some(signal), "{}", describe(&out));
    }
}

/// A scenario path that is no regular file (/dev/zero, a FIFO, a
/// directory) or a file beyond the size a scenario may have is refused at
/// once, naming the file: before, /dev/zero was read until memory ran out
/// and a FIFO blocked `design` forever.
#[test]
fn a_scenario_that_is_no_regular_file_or_too_large_is_refused_at_once() {
    let dir = temp_dir("bad-scenario-file");
    let fifo = dir.join("fifo.toml");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(made.success());
    let huge = dir.join("huge.toml");
    std::fs::File::create(&huge)
        .unwrap()
        .set_len(1 << 30)
        .unwrap();
    for path in [
        std::path::PathBuf::from("/dev/zero"),
        fifo,
        dir.to_path_buf(),
        huge,
    ] {
        for command in ["design", "up"] {
            let mut cmd = flexloop();
            cmd.arg(command).arg(&path);
            if command == "up" {
                cmd.args(["--run-dir"]).arg(dir.join("run"));
            }
            let out = run_bounded(cmd, Duration::from_secs(30));
            assert_eq!(
                out.status.code(),
                Some(2),
                "{command} {path:?}: {}",
                describe(&out)
            );
            let err = String::from_utf8_lossy(&out.stderr);
            assert!(
                err.contains(&path.display().to_string())
                    && (err.contains("not a regular file") || err.contains("beyond the")),
                "{command} {path:?}: {err}"
            );
        }
    }
    assert!(!dir.join("run").exists());
}
