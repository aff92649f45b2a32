//! Model files that would exhaust the machine (docs/own-plant.md): anything but a
//! regular file, a file beyond the cap, archives and MAT-files declaring or
//! inflating to more than any model flexloop takes, and a fuzz of damaged
//! files. Each is refused naming the file, the array where there is one,
//! and the reason, within seconds and a bounded memory: nothing is read,
//! inflated or allocated beyond the caps of `flexloop_modelfile::limits`.
//!
//! Every case runs on a thread of its own, waited for at most 30 s (a
//! generous bound against a hang, not a timing claim: each takes
//! milliseconds); the memory bound is asserted on this test process's peak
//! resident size, which every case running in it shares.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use flexloop_modelfile::limits::{MAX_ARRAY_BYTES, MAX_ARRAYS, MAX_FILE_BYTES};
use flexloop_modelfile::{ModelArrays, ModelFileError, ModelFileErrorKind};

/// The bound against a hang; each case takes milliseconds.
const HANG: Duration = Duration::from_secs(30);
/// The memory no case may make this process's peak resident size exceed.
const PEAK_RSS_BYTES: u64 = 200 << 20;

/// A fresh directory for one test.
fn dir(test: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("hostile-{test}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// This process's peak resident size so far.
fn peak_rss_bytes() -> u64 {
    // SAFETY: getrusage fills the zeroed struct it is given.
    let usage = unsafe {
        let mut usage: libc::rusage = std::mem::zeroed();
        assert_eq!(libc::getrusage(libc::RUSAGE_SELF, &mut usage), 0);
        usage
    };
    // Linux gives ru_maxrss in KiB.
    u64::try_from(usage.ru_maxrss).unwrap() * 1024
}

/// Reads `path` on a thread of its own, at most [`HANG`]: the result and
/// how long it took; the process's peak memory checked after.
fn read_bounded(path: &Path) -> (Result<ModelArrays, ModelFileError>, Duration) {
    read_bounded_quietly(path, false)
}

/// [`read_bounded`], saying what it took unless `quiet`.
fn read_bounded_quietly(
    path: &Path,
    quiet: bool,
) -> (Result<ModelArrays, ModelFileError>, Duration) {
    let (sender, receiver) = mpsc::channel();
    let owned = path.to_path_buf();
    std::thread::spawn(move || {
        let since = Instant::now();
        let result = ModelArrays::read(&owned);
        let _ = sender.send((result, since.elapsed()));
    });
    let (result, took) = receiver
        .recv_timeout(HANG)
        .unwrap_or_else(|_| panic!("{}: still reading after {HANG:?}", path.display()));
    let peak = peak_rss_bytes();
    assert!(
        peak < PEAK_RSS_BYTES,
        "{}: peak resident size {} MiB",
        path.display(),
        peak >> 20
    );
    if !quiet {
        println!(
            "{}: {took:?}, peak resident size of the tests so far {} MiB",
            path.display(),
            peak >> 20
        );
    }
    (result, took)
}

/// `path` is refused, the error naming it (and `array`, if given): its kind.
fn refused(path: &Path, array: Option<&str>) -> ModelFileErrorKind {
    let (result, _) = read_bounded(path);
    let error = match result {
        Ok(arrays) => panic!("{}: read {:?}", path.display(), arrays.names()),
        Err(e) => e,
    };
    let message = error.to_string();
    assert!(
        message.starts_with(&path.display().to_string()),
        "{message}"
    );
    assert_eq!(error.array.as_deref(), array, "{message}");
    if let Some(name) = array {
        assert!(message.contains(&format!("array `{name}`")), "{message}");
    }
    error.kind
}

/// A `.npy` array (format version 1.0) with the header dict padded to 64 bytes.
fn npy(descr: &str, shape: &str, data: &[u8]) -> Vec<u8> {
    let mut dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    while (10 + dict.len() + 1) % 64 != 0 {
        dict.push(' ');
    }
    dict.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&u16::try_from(dict.len()).unwrap().to_le_bytes());
    bytes.extend_from_slice(dict.as_bytes());
    bytes.extend_from_slice(data);
    bytes
}

fn f64s(values: &[f64]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// An `.npz` archive of stored `members`, as the zip crate writes it.
fn npz(members: &[(String, Vec<u8>)]) -> Vec<u8> {
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    for (name, bytes) in members {
        let options = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Stored);
        zip.start_file(name.as_str(), options).unwrap();
        zip.write_all(bytes).unwrap();
    }
    zip.finish().unwrap().into_inner()
}

/// A raw deflate stream (`zlib`: with the zlib header) that inflates to
/// `prefix` and zeros, `total` bytes in all, in about `total / 1000` bytes:
/// one 1 MiB block of zeros compressed after the prefix, then repeated (each
/// copy refers back only to zeros, so every copy inflates alike).
fn deflate_bomb(prefix: &[u8], total: u64, zlib: bool) -> Vec<u8> {
    use flate2::{Compress, Compression, FlushCompress};
    let mut compress = Compress::new(Compression::best(), zlib);
    let mut chunk = |input: &[u8], flush| {
        let mut out = Vec::with_capacity(input.len() + 1024);
        let before = compress.total_in();
        compress.compress_vec(input, &mut out, flush).unwrap();
        assert_eq!(compress.total_in() - before, input.len() as u64);
        out
    };
    let zeros = vec![0u8; 1 << 20];
    let mut head = prefix.to_vec();
    head.extend_from_slice(&zeros);
    let mut stream = chunk(&head, FlushCompress::Sync);
    let block = chunk(&zeros, FlushCompress::Sync);
    let copies = (total - head.len() as u64).div_ceil(1 << 20);
    for _ in 0..copies {
        stream.extend_from_slice(&block);
    }
    // The final (empty) block; a zlib stream's checksum after it is of what
    // the compressor saw, not of the whole: a reader stops long before.
    stream.extend(chunk(&[], FlushCompress::Finish));
    stream
}

/// A zip archive of one deflated member `name` whose data are `deflated`,
/// declaring `declared` bytes inflated (written by hand: the zip crate
/// writes what it compresses, and a bomb lies or is too large to compress).
fn zip_with_deflated(name: &str, deflated: &[u8], declared: u32) -> Vec<u8> {
    let compressed = u32::try_from(deflated.len()).unwrap();
    let name_len = u16::try_from(name.len()).unwrap();
    let mut zip = Vec::new();
    // Local file header: version 2.0, no flags, deflate, 1980-01-01, CRC 0.
    zip.extend_from_slice(&0x0403_4b50u32.to_le_bytes());
    for half in [20u16, 0, 8, 0, 0x21] {
        zip.extend_from_slice(&half.to_le_bytes());
    }
    for word in [0u32, compressed, declared] {
        zip.extend_from_slice(&word.to_le_bytes());
    }
    zip.extend_from_slice(&name_len.to_le_bytes());
    zip.extend_from_slice(&0u16.to_le_bytes());
    zip.extend_from_slice(name.as_bytes());
    zip.extend_from_slice(deflated);
    let directory = zip.len() as u32;
    zip.extend_from_slice(&0x0201_4b50u32.to_le_bytes());
    for half in [20u16, 20, 0, 8, 0, 0x21] {
        zip.extend_from_slice(&half.to_le_bytes());
    }
    for word in [0u32, compressed, declared] {
        zip.extend_from_slice(&word.to_le_bytes());
    }
    for half in [name_len, 0, 0, 0, 0] {
        zip.extend_from_slice(&half.to_le_bytes());
    }
    zip.extend_from_slice(&0u32.to_le_bytes()); // external attributes
    zip.extend_from_slice(&0u32.to_le_bytes()); // local header at 0
    zip.extend_from_slice(name.as_bytes());
    let directory_len = zip.len() as u32 - directory;
    zip.extend_from_slice(&0x0605_4b50u32.to_le_bytes());
    for half in [0u16, 0, 1, 1] {
        zip.extend_from_slice(&half.to_le_bytes());
    }
    zip.extend_from_slice(&directory_len.to_le_bytes());
    zip.extend_from_slice(&directory.to_le_bytes());
    zip.extend_from_slice(&0u16.to_le_bytes());
    zip
}

/// A level-5 MAT-file header (little endian) as scipy writes it.
fn mat_header() -> Vec<u8> {
    let mut header = b"MATLAB 5.0 MAT-file Platform: posix, Created by: flexloop tests".to_vec();
    header.resize(116, b' ');
    header.extend_from_slice(&[0; 8]);
    header.extend_from_slice(&[0x00, 0x01, b'I', b'M']);
    header
}

/// A tag: data type and byte count, little endian.
fn tag(data_type: u32, len: u32) -> Vec<u8> {
    let mut tag = data_type.to_le_bytes().to_vec();
    tag.extend_from_slice(&len.to_le_bytes());
    tag
}

/// The start of a `miMATRIX` element of a double array `name` of `dims`
/// whose real part declares `data_len` bytes, the element `declared` bytes
/// (its data, if any, follow).
fn mat_double_head(name: &str, dims: &[i32], data_len: u32, declared: u32) -> Vec<u8> {
    let mut e = tag(14, declared);
    e.extend(tag(6, 8));
    e.extend_from_slice(&[6, 0, 0, 0, 0, 0, 0, 0]); // mxDOUBLE_CLASS
    e.extend(tag(5, 4 * dims.len() as u32));
    for d in dims {
        e.extend_from_slice(&d.to_le_bytes());
    }
    e.resize(e.len().next_multiple_of(8), 0);
    e.extend(tag(1, name.len() as u32));
    e.extend_from_slice(name.as_bytes());
    e.resize(e.len().next_multiple_of(8), 0);
    e.extend(tag(9, data_len)); // miDOUBLE
    e
}

/// A whole uncompressed double variable `name` of `dims` with `values`.
fn mat_double(name: &str, dims: &[i32], values: &[f64]) -> Vec<u8> {
    let data = f64s(values);
    let head_len = mat_double_head(name, dims, 0, 0).len() - 8;
    let declared = (head_len + data.len().next_multiple_of(8)) as u32;
    let mut e = mat_double_head(name, dims, data.len() as u32, declared);
    e.extend_from_slice(&data);
    e.resize(e.len().next_multiple_of(8), 0);
    e
}

#[test]
fn anything_but_a_regular_file_is_refused_without_reading_it() {
    let dir = dir("not-regular");
    // A FIFO: opened for reading, it would block until a writer came.
    let fifo = dir.join("plant.npz");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(made.success());
    let found = |kind| match kind {
        ModelFileErrorKind::NotARegularFile { found } => found,
        other => panic!("{other:?}"),
    };
    assert_eq!(found(refused(&fifo, None)), "a FIFO (named pipe)");
    // A device, by a link named like a model file: /dev/zero never ends.
    let zero = dir.join("zero.mat");
    std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
    assert_eq!(found(refused(&zero, None)), "a character device");
    // /dev/zero itself has no model file's extension.
    assert!(matches!(
        refused(Path::new("/dev/zero"), None),
        ModelFileErrorKind::UnknownFormat { extension: None }
    ));
    let directory = dir.join("model.npz");
    std::fs::create_dir(&directory).unwrap();
    assert_eq!(found(refused(&directory, None)), "a directory");
    let socket = dir.join("plant.mat");
    let _listener = std::os::unix::net::UnixListener::bind(&socket).unwrap();
    assert_eq!(found(refused(&socket, None)), "a socket");
    // A link to a regular file is read as the file.
    let real = dir.join("real.npz");
    let members = [("ts.npy".to_string(), npy("<f8", "()", &f64s(&[1e-4])))];
    std::fs::write(&real, npz(&members)).unwrap();
    let link = dir.join("link.npz");
    std::os::unix::fs::symlink(&real, &link).unwrap();
    let (read, _) = read_bounded(&link);
    assert_eq!(read.unwrap().scalar("ts").unwrap(), Some(1e-4));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_file_beyond_the_cap_is_refused_from_its_size() {
    let dir = dir("too-big");
    // Sparse files: their size without their disk space.
    for (name, len) in [("plant.npz", MAX_FILE_BYTES + 1), ("plant.mat", 4 << 30)] {
        let path = dir.join(name);
        std::fs::File::create(&path).unwrap().set_len(len).unwrap();
        let kind = refused(&path, None);
        assert_eq!(kind, ModelFileErrorKind::FileTooLarge { bytes: len });
        assert!(kind.to_string().contains("more than the 16 MiB"), "{kind}");
    }
    // At the cap the file is read (and is no model: all zeros).
    let path = dir.join("at-cap.mat");
    std::fs::File::create(&path)
        .unwrap()
        .set_len(MAX_FILE_BYTES)
        .unwrap();
    assert!(matches!(
        refused(&path, None),
        ModelFileErrorKind::MatLevel4
    ));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_npz_member_inflating_beyond_the_cap_stops_there() {
    let dir = dir("npz-bomb");
    let header = npy("<f8", "(2, 2)", &[]);
    let bomb = deflate_bomb(&header, 2 << 30, false);
    assert!(bomb.len() < 3 << 20, "{} bytes", bomb.len());
    // The archive declares the 2 GiB it inflates to: refused from the declaration.
    let honest = dir.join("honest.npz");
    std::fs::write(&honest, zip_with_deflated("M.npy", &bomb, 2 << 30)).unwrap();
    assert_eq!(
        refused(&honest, Some("M")),
        ModelFileErrorKind::ArrayDataTooLarge {
            bytes: Some(2 << 30)
        }
    );
    // It declares less than it inflates to: inflating stops at the cap (or
    // at the declared size, where the zip crate stops), never at 2 GiB.
    let lying = dir.join("lying.npz");
    let declared = u32::try_from(MAX_ARRAY_BYTES / 2).unwrap();
    std::fs::write(&lying, zip_with_deflated("M.npy", &bomb, declared)).unwrap();
    let (result, took) = read_bounded(&lying);
    let error = result.unwrap_err();
    assert_eq!(error.array.as_deref(), Some("M"), "{error}");
    assert!(
        matches!(
            error.kind,
            ModelFileErrorKind::ArrayDataTooLarge { bytes: None }
                | ModelFileErrorKind::Corrupt { .. }
        ),
        "{error}"
    );
    assert!(took < HANG);
    // A member declared beyond the cap is told by its header's shape where
    // that is too large (a finite-element model of 1000 degrees of freedom).
    let header = npy("<f8", "(1000, 1000)", &[]);
    let big = deflate_bomb(&header, 8_000_000, false);
    let fe = dir.join("fe.npz");
    std::fs::write(&fe, zip_with_deflated("K.npy", &big, 8_000_000)).unwrap();
    assert_eq!(
        refused(&fe, Some("K")),
        ModelFileErrorKind::ArrayTooLarge {
            shape: vec![1000, 1000]
        }
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_npy_header_declaring_a_huge_shape_is_refused_before_its_data() {
    let dir = dir("npy-shape");
    for (shape, declared) in [
        ("(100000, 100000)", vec![100_000, 100_000]),
        ("(129, 129)", vec![129, 129]),
        ("(64, 64, 64)", vec![64, 64, 64]),
        // Beyond u64: npyz would multiply it out unchecked.
        (
            "(1099511627776, 1099511627776, 99999999999999999999999)",
            vec![1 << 40, 1 << 40, u64::MAX],
        ),
    ] {
        let path = dir.join("plant.npz");
        let members = [("K.npy".to_string(), npy("<f8", shape, &f64s(&[1.0; 4])))];
        std::fs::write(&path, npz(&members)).unwrap();
        let kind = refused(&path, Some("K"));
        assert_eq!(
            kind,
            ModelFileErrorKind::ArrayTooLarge { shape: declared },
            "{shape}"
        );
        assert!(kind.to_string().contains("at most 128 in each dimension"));
    }
    // 128 × 128, the most the loop takes, reads.
    let path = dir.join("largest.npz");
    let members = [(
        "A.npy".to_string(),
        npy("<f8", "(128, 128)", &f64s(&[0.5; 128 * 128])),
    )];
    std::fs::write(&path, npz(&members)).unwrap();
    let (read, _) = read_bounded(&path);
    assert_eq!(read.unwrap().array("A").unwrap().shape(), &[128, 128]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_mat_variable_declaring_huge_dimensions_is_refused_before_its_data() {
    let dir = dir("mat-dims");
    let path = dir.join("plant.mat");
    // Uncompressed: 100000 × 100000 declared, four numbers given.
    let mut file = mat_header();
    file.extend(mat_double("M", &[2, 2], &[1.0, 0.0, 0.0, 1.0]));
    file.extend(mat_double("K", &[100_000, 100_000], &[1.0; 4]));
    std::fs::write(&path, &file).unwrap();
    assert_eq!(
        refused(&path, Some("K")),
        ModelFileErrorKind::ArrayTooLarge {
            shape: vec![100_000, 100_000]
        }
    );
    // Its real part declaring 4 GiB within a small element: the framing.
    let mut file = mat_header();
    let mut element = mat_double_head("M", &[2, 2], u32::MAX, 0);
    element.extend_from_slice(&f64s(&[1.0; 4]));
    let declared = (element.len() - 8) as u32;
    element[4..8].copy_from_slice(&declared.to_le_bytes());
    file.extend(element);
    std::fs::write(&path, &file).unwrap();
    let kind = refused(&path, None);
    assert!(
        kind.to_string().contains("variable 1 of 1 cannot be read"),
        "{kind}"
    );
    // An uncompressed variable beyond one array's bytes (its dimensions
    // within the bound, its stored bytes not).
    let mut file = mat_header();
    let values = vec![0.0; (MAX_ARRAY_BYTES / 8) as usize + 16];
    file.extend(mat_double("A", &[128, 128], &values));
    std::fs::write(&path, &file).unwrap();
    assert!(matches!(
        refused(&path, Some("A")),
        ModelFileErrorKind::ArrayDataTooLarge { bytes: Some(_) }
    ));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_compressed_mat_variable_inflating_beyond_the_cap_stops_there() {
    let dir = dir("mat-bomb");
    let path = dir.join("plant.mat");
    for (dims, expected) in [
        // Small dimensions, 1 GiB of data: inflating stops at the cap.
        (
            vec![2, 2],
            ModelFileErrorKind::ArrayDataTooLarge { bytes: None },
        ),
        // Huge dimensions: told from the first inflated bytes.
        (
            vec![11_585, 11_585],
            ModelFileErrorKind::ArrayTooLarge {
                shape: vec![11_585, 11_585],
            },
        ),
    ] {
        let head = mat_double_head("M", &dims, 1 << 30, (1 << 30) + 64);
        let bomb = deflate_bomb(&head, 1 << 30, true);
        assert!(bomb.len() < 2 << 20, "{} bytes", bomb.len());
        let mut file = mat_header();
        file.extend(tag(15, bomb.len() as u32));
        file.extend_from_slice(&bomb);
        std::fs::write(&path, &file).unwrap();
        assert_eq!(refused(&path, Some("M")), expected);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn more_arrays_than_any_model_has_are_refused() {
    let dir = dir("many");
    let many = MAX_ARRAYS + 1;
    let members: Vec<(String, Vec<u8>)> = (0..many)
        .map(|i| (format!("x{i}.npy"), npy("<f8", "()", &f64s(&[1.0]))))
        .collect();
    let path = dir.join("plant.npz");
    std::fs::write(&path, npz(&members)).unwrap();
    assert_eq!(
        refused(&path, None),
        ModelFileErrorKind::TooManyArrays {
            count: Some(many as u64)
        }
    );
    let path = dir.join("plant.mat");
    let mut file = mat_header();
    for i in 0..many {
        file.extend(mat_double(&format!("x{i}"), &[1, 1], &[1.0]));
    }
    std::fs::write(&path, &file).unwrap();
    assert_eq!(
        refused(&path, None),
        ModelFileErrorKind::TooManyArrays { count: None }
    );
    // 180 000 empty members, a file just below the cap: the archive's
    // directory is all there is, and all the zip crate reads of it.
    let members: Vec<(String, Vec<u8>)> = (0..180_000)
        .map(|i| (format!("{i:x}"), Vec::new()))
        .collect();
    let path = dir.join("directory.npz");
    std::fs::write(&path, npz(&members)).unwrap();
    println!(
        "{}: {} bytes",
        path.display(),
        std::fs::metadata(&path).unwrap().len()
    );
    assert_eq!(
        refused(&path, None),
        ModelFileErrorKind::TooManyArrays {
            count: Some(180_000)
        }
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A small xorshift generator: the fuzz is the same on every run.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// Damaged copies of valid files (bytes flipped, set to 0 or 0xff, sizes
/// and dimensions made huge, pieces cut out or repeated): each read ends,
/// within the bounds, as arrays or as an error naming the file; none
/// crashes, hangs or allocates beyond the caps.
#[test]
fn a_fuzz_of_damaged_model_files_ends_in_arrays_or_errors() {
    let dir = dir("fuzz");
    let m = f64s(&[2.0, 0.0, 0.0, 3.0]);
    let valid_npz = npz(&[
        ("M.npy".to_string(), npy("<f8", "(2, 2)", &m)),
        ("B.npy".to_string(), npy("<f8", "(2,)", &f64s(&[1.0, 0.0]))),
    ]);
    let mut valid_mat = mat_header();
    valid_mat.extend(mat_double("M", &[2, 2], &[2.0, 0.0, 0.0, 3.0]));
    valid_mat.extend(mat_double("B", &[2, 1], &[1.0, 0.0]));
    // A compressed copy of the same variables, as MATLAB's default writes.
    let mut compressed_mat = mat_header();
    for element in [
        mat_double("M", &[2, 2], &[2.0, 0.0, 0.0, 3.0]),
        mat_double("B", &[2, 1], &[1.0, 0.0]),
    ] {
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        z.write_all(&element).unwrap();
        let z = z.finish().unwrap();
        compressed_mat.extend(tag(15, z.len() as u32));
        compressed_mat.extend(z);
    }
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let since = Instant::now();
    let mut outcomes = [0usize; 2];
    for (valid, extension) in [
        (&valid_npz, "npz"),
        (&valid_mat, "mat"),
        (&compressed_mat, "mat"),
    ] {
        let path = dir.join(format!("fuzz.{extension}"));
        let (whole, _) = read_bounded_bytes(&path, valid);
        assert!(whole.is_ok(), "{:?}", whole.unwrap_err().to_string());
        for _ in 0..700 {
            let mut bytes = valid.clone();
            for _ in 0..1 + rng.below(4) {
                let at = rng.below(bytes.len());
                match rng.below(6) {
                    0 => bytes[at] ^= 1 << rng.below(8),
                    1 => bytes[at] = 0xff,
                    2 => bytes[at] = 0,
                    // A huge length or dimension wherever a word is.
                    3 => {
                        let at = at.min(bytes.len() - 4);
                        bytes[at..at + 4].copy_from_slice(&0x7fff_fff0u32.to_le_bytes());
                    }
                    4 => {
                        let len = rng.below(bytes.len() - at).min(64);
                        bytes.drain(at..at + len);
                    }
                    _ => {
                        let len = rng.below(bytes.len() - at).min(64);
                        let piece = bytes[at..at + len].to_vec();
                        bytes.splice(at..at, piece);
                    }
                }
                if bytes.len() < 8 {
                    break;
                }
            }
            let (result, _) = read_bounded_bytes(&path, &bytes);
            match result {
                Ok(_) => outcomes[0] += 1,
                Err(e) => {
                    assert!(
                        e.to_string().starts_with(&path.display().to_string()),
                        "{e}"
                    );
                    outcomes[1] += 1;
                }
            }
        }
    }
    println!(
        "fuzz: {} read, {} refused, in {:?}",
        outcomes[0],
        outcomes[1],
        since.elapsed()
    );
    assert!(outcomes[1] > 0);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// [`read_bounded`] of `bytes` written to `path`.
fn read_bounded_bytes(
    path: &Path,
    bytes: &[u8],
) -> (Result<ModelArrays, ModelFileError>, Duration) {
    std::fs::write(path, bytes).unwrap();
    read_bounded_quietly(path, true)
}
