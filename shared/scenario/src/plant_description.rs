//! The parts of `[plant]` with which a user describes a structure of their
//! own (docs/own-plant.md): the physical parameters of the built-in chain,
//! lumped mass–spring–damper networks, model files, and modal damping.
//! Turning them into a model is flexloop-design's job (`plants::own`).

use serde::{Deserialize, Deserializer};
use std::path::PathBuf;

/// The models a user brings (the others are built in).
pub const OWN_MODELS: [&str; 3] = ["lumped", "second-order", "state-space"];

/// Modal damping of the flexible modes: one ζ for all, or one per flexible
/// mode in frequency order.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(untagged)]
pub enum ModalZeta {
    Uniform(f64),
    PerMode(Vec<f64>),
}

impl ModalZeta {
    /// Every ζ given, for range checks.
    pub fn values(&self) -> Vec<f64> {
        match self {
            ModalZeta::Uniform(z) => vec![*z],
            ModalZeta::PerMode(v) => v.clone(),
        }
    }
}

/// Rayleigh damping D = α M + β K: ζ_i = α / (2 ω_i) + β ω_i / 2.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rayleigh {
    #[serde(default)]
    pub alpha: f64,
    #[serde(default)]
    pub beta: f64,
}

/// Where an element of a lumped network attaches: at one mass (a force on
/// it, its position, a spring or damper to the ground) or between two
/// (a force pair, +f on the second and −f on the first; the relative
/// position q_second − q_first; a spring or damper joining them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Attachment {
    At(usize),
    Between(usize, usize),
}

impl Attachment {
    pub fn masses(self) -> Vec<usize> {
        match self {
            Attachment::At(i) => vec![i],
            Attachment::Between(i, j) => vec![i, j],
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AttachmentText {
    at: Option<usize>,
    between: Option<Vec<usize>>,
}

impl AttachmentText {
    fn attachment<E: serde::de::Error>(self) -> Result<Attachment, E> {
        match (self.at, self.between) {
            (Some(i), None) => Ok(Attachment::At(i)),
            (None, Some(pair)) => match pair[..] {
                [i, j] => Ok(Attachment::Between(i, j)),
                _ => Err(E::custom(format!(
                    "`between` names two masses, got {}",
                    pair.len()
                ))),
            },
            (Some(_), Some(_)) => Err(E::custom("give `at` or `between`, not both")),
            (None, None) => Err(E::custom(
                "give `at = MASS` or `between = [MASS, MASS]` (masses count from 0)",
            )),
        }
    }
}

impl<'de> Deserialize<'de> for Attachment {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        AttachmentText::deserialize(d)?.attachment()
    }
}

/// A spring of a lumped network, N/m (`at`: to the ground).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spring {
    pub attachment: Attachment,
    pub stiffness: f64,
}

/// A damper of a lumped network, N s/m (`at`: to the ground).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Damper {
    pub attachment: Attachment,
    pub damping: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SpringText {
    at: Option<usize>,
    between: Option<Vec<usize>>,
    stiffness: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DamperText {
    at: Option<usize>,
    between: Option<Vec<usize>>,
    damping: f64,
}

impl<'de> Deserialize<'de> for Spring {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let t = SpringText::deserialize(d)?;
        Ok(Spring {
            attachment: AttachmentText {
                at: t.at,
                between: t.between,
            }
            .attachment()?,
            stiffness: t.stiffness,
        })
    }
}

impl<'de> Deserialize<'de> for Damper {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let t = DamperText::deserialize(d)?;
        Ok(Damper {
            attachment: AttachmentText {
                at: t.at,
                between: t.between,
            }
            .attachment()?,
            damping: t.damping,
        })
    }
}

/// The fields that name a file relative to the scenario's directory: the
/// plant's model and the IO observer's correction filter.
const FILE_FIELDS: [(&str, &str); 5] = [
    ("plant", "file"),
    ("plant", "design_file"),
    ("observer", "correction_file"),
    ("controller", "workdir"),
    ("observer", "workdir"),
];

/// A copy of a scenario written elsewhere (a variant `bench` or `chaos`
/// runs, a `flexloop set`) keeps its files: every relative file field
/// ([`FILE_FIELDS`]) and a controller program is made absolute, anchored at
/// the directory of `scenario`, the file the table was read from.
pub fn anchor_files(table: &mut toml::Table, scenario: &std::path::Path) {
    let dir = scenario
        .parent()
        .map(std::path::Path::to_path_buf)
        .unwrap_or_default();
    let dir = std::fs::canonicalize(&dir).unwrap_or(dir);
    for (section, key) in FILE_FIELDS {
        let Some(section) = table.get_mut(section).and_then(|p| p.as_table_mut()) else {
            continue;
        };
        let Some(toml::Value::String(file)) = section.get(key) else {
            continue;
        };
        let file = PathBuf::from(file);
        if file.is_relative() {
            section.insert(
                key.into(),
                toml::Value::String(dir.join(file).display().to_string()),
            );
        }
    }
    // A program of one's own: its path (one with a `/`) and, absent, its
    // working directory (the scenario's) are relative to the directory too.
    for section in ["controller", "observer"] {
        anchor_program(table, section, &dir);
    }
}

fn anchor_program(table: &mut toml::Table, section: &str, dir: &std::path::Path) {
    let Some(controller) = table.get_mut(section).and_then(|c| c.as_table_mut()) else {
        return;
    };
    let Some(toml::Value::Array(exec)) = controller.get_mut("exec") else {
        return;
    };
    if let Some(toml::Value::String(program)) = exec.first_mut()
        && program.contains('/')
        && std::path::Path::new(program.as_str()).is_relative()
    {
        *program = dir.join(program.as_str()).display().to_string();
    }
    if !controller.contains_key("workdir") {
        controller.insert(
            "workdir".into(),
            toml::Value::String(dir.display().to_string()),
        );
    }
}
