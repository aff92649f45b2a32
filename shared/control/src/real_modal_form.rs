//! A user's first-order model ẋ = A x + B u, y = C x (+ D u, D = 0) in any
//! coordinates (MATLAB, python-control, an identification) brought to the
//! modal form of [`crate::modal`] (docs/control.md §1.1, type 1 (2.9)), in
//! real arithmetic (nalgebra has no non-symmetric eigenvectors).
//!
//! Method:
//! 1. A is balanced (a diagonal similarity, [`crate::linalg::balance`]):
//!    physical coordinates mix entries of order ω² and 1.
//! 2. Eigenvalues from the real Schur form, classified and clustered (the
//!    tolerances are the constants below): zero (rigid-body), complex pairs
//!    σ ± iω_d with σ ≤ 0 (flexible); real nonzero and unstable ones are
//!    refused. Equal pairs form one cluster of multiplicity k (repeated
//!    frequencies, e.g. two identical bending modes).
//! 3. Real invariant subspaces by SVD: per flexible cluster λ = σ + iω_d of
//!    multiplicity k, S = span{Re v, Im v : (A − λI)v = 0} (dimension 2k, the
//!    real invariant subspace null(A² − 2σA + |λ|²I), computed from the
//!    complex A − λI, whose rounding is ε‖A‖ rather than ε‖A‖²; recomputed
//!    once with σ, |λ|² refined from the projected block). The rigid modes'
//!    subspace S₀ (dimension 2·n_rigid; a free structure's first-order model
//!    has 2×2 Jordan blocks at 0, checked as dim ker A = n_rigid and
//!    dim ker A² = 2·n_rigid) is the orthogonal complement of the flexible
//!    clusters' left invariant subspaces (those of Aᵀ), i.e. null(A²) without
//!    forming A². The subspaces give a real basis T in which T⁻¹AT is
//!    block-diagonal; B and C are projected (B̄ = T⁻¹B, C̄ = CT).
//! 4. Per cluster, with Ā its block: Ā² − 2σĀ + |λ|²I = 0, so
//!    (sI − Ā)⁻¹ = (sI + Ā − 2σI)/(s² − 2σs + |λ|²) and the cluster's
//!    transfer function is (s C̄B̄ + C̄(Ā + 2ζωI)B̄)/(s² + 2ζωs + ω²). A
//!    structural mode (force input into the acceleration, position output)
//!    has C̄B̄ = 0 and a residue R = C̄(Ā + 2ζωI)B̄ = Σ φ_s,i φ_a,iᵀ of rank
//!    ≤ k; a flexible input projection B̄ of rank > k is not a force, a
//!    nonzero C̄B̄ is a velocity output. For the rigid cluster (Ā² = 0) the
//!    transfer function is (s C̄B̄ + C̄ĀB̄)/s²: C̄B̄ = 0 again, and the rigid
//!    modes must be controllable (rank ĀB̄ = n_rigid) and observable
//!    (rank C̄Ā = n_rigid).
//! 5. The residue is split into modes by its SVD, R = Σ s_i u_i v_iᵀ:
//!    φ_s,i = √s_i u_i, φ_a,i = √s_i v_i, the i-th largest first.
//!
//! Normalisation: a first-order model carries no mass matrix, so mass
//! normalisation is not defined. Each mode is scaled so that |φ_a,i| =
//! |φ_s,i| (2-norms), with the sign of [`crate::modal`] (φ_a at the first
//! input positive; else its largest entry; else φ_s's largest). Every
//! input–output quantity (φ_s,i φ_a,iᵀ, frequencies, ζ, T_DC, the transfer
//! function, the ZOH of [`ModalModel::state_space`]) is independent of that
//! choice; φ_a and φ_s alone are not. Within a cluster of k > 1 equal modes
//! (and among several rigid modes) only the sum of the products is defined;
//! the SVD picks one split, deterministic for the same input. A mode that no
//! input reaches (|B̄| at rounding level) gets φ_a = φ_s = 0: from rest its
//! output is zero. The model has no nodal shapes (`shapes` is `None`).
//!
//! Modes are sorted rigid first (largest residue first), then by frequency
//! (within a cluster, largest residue first).

use crate::linalg::{balance, eigenvalues};
use crate::modal::ModalModel;
use crate::plant_model_error::{PlantModelError, PlantModelReason as R, check_array};
use nalgebra::{Complex, DMatrix};

/// An eigenvalue with |λ| at most this fraction of ‖A‖ (Frobenius, balanced)
/// is zero: a rigid-body Jordan pair perturbed by rounding ε splits by about
/// at most √ε·‖A‖ ≈ 1.5e-8·‖A‖ (the thesis chain in mixed coordinates:
/// 1.5e-5 rad/s at ‖A‖ ≈ 3e8), so a flexible mode would have to lie six
/// decades below the model's scale to be taken as rigid.
pub const ZERO_EIGENVALUE_TOL: f64 = 1e-6;
/// An eigenvalue with |Im λ| at most this fraction of |λ| is real (a
/// critically damped pair splits by about √ε).
pub const REAL_EIGENVALUE_TOL: f64 = 1e-6;
/// An eigenvalue with Re λ above this fraction of |λ| is unstable; below it,
/// a slightly positive σ of an undamped mode is rounding and ζ becomes 0.
pub const UNSTABLE_TOL: f64 = 1e-9;
/// Complex eigenvalues closer than this fraction of |λ| are one repeated
/// frequency. Modes that close are indistinguishable in any measurement; a
/// pair at this distance taken as one changes the model by about this much.
pub const CLUSTER_TOL: f64 = 1e-7;
/// A singular value at most this fraction of the largest is zero (ranks of
/// the projected gains).
const RANK_TOL: f64 = 1e-8;
/// A singular value of A at most this fraction of ‖A‖ (of A² at most this
/// fraction of ‖A‖²) is zero. Rounding leaves about ε‖A‖ (ε‖A‖², A² being a
/// computed product) on a true kernel; a physical A = [[0, I], [−M⁻¹K, …]]
/// has nonzero singular values down to about 1/‖A‖ of its norm, which
/// balancing cannot remove once the coordinates are mixed.
const KERNEL_TOL: f64 = 1e-12;
/// The largest singular value taken into an invariant subspace may be this
/// fraction of ‖A‖ (the scale of A − λI's rounding); more means the eigenvalue is defective (a Jordan
/// block), not a mode.
const NULL_TOL: f64 = 1e-6;
/// |C̄B̄| at most this fraction of |C̄||B̄| counts as zero (no velocity
/// output, no position input).
const STRUCTURE_TOL: f64 = 1e-6;
/// Projected gains below this fraction of |B̄| (|C̄|) over all modes are
/// rounding: the mode is not reached (not seen).
const NOISE_FLOOR: f64 = 1e-10;
/// Off-diagonal blocks of T⁻¹AT above this fraction of |T⁻¹AT| mean the
/// clusters were not separated.
const SEPARATION_TOL: f64 = 1e-6;

/// One mode's (φ_s, φ_a).
type ModeGains = (Vec<f64>, Vec<f64>);

/// One cluster of equal complex eigenvalues (upper half plane).
struct Cluster {
    multiplicity: usize,
    sigma: f64,
    abs2: f64,
}

impl Cluster {
    fn frequency_hz(&self) -> f64 {
        self.abs2.max(0.0).sqrt() / (2.0 * std::f64::consts::PI)
    }
}

/// The modal model of ẋ = A x + B u, y = C x + D u (A n×n, B n×m, C p×n,
/// D p×m optional and all zeros). See the module doc for the method, the
/// normalisation and what is refused.
pub fn modal_from_state_space(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    c: &DMatrix<f64>,
    d: Option<&DMatrix<f64>>,
) -> Result<ModalModel, PlantModelError> {
    let n = a.nrows();
    if n == 0 {
        return Err(PlantModelError::new(
            "A",
            R::OutOfRange("has no states".into()),
        ));
    }
    check_array(a, "A", n, n)?;
    let m = b.ncols();
    check_array(b, "B", n, m)?;
    let p = c.nrows();
    check_array(c, "C", p, n)?;
    if let Some(d) = d {
        check_array(d, "D", p, m)?;
        if d.iter().any(|v| *v != 0.0) {
            return Err(PlantModelError::new("D", R::Feedthrough));
        }
    }
    let fail = |what| PlantModelError::new("A", R::NoConvergence(what));
    let (ab, scale) = balance(a).map_err(|_| fail("balancing"))?;
    let mut bb = b.clone();
    let mut cb = c.clone();
    for i in 0..n {
        bb.row_mut(i).scale_mut(1.0 / scale[i]);
        cb.column_mut(i).scale_mut(scale[i]);
    }
    let eig = eigenvalues(&ab).map_err(|_| fail("Schur decomposition"))?;
    let (n_zero, mut clusters) = classify(&eig, ab.norm())?;

    // Invariant subspaces: rigid first, then the clusters by frequency.
    let mut bases: Vec<DMatrix<f64>> = Vec::new();
    let mut left: Vec<DMatrix<f64>> = Vec::new();
    let at_t = ab.transpose();
    for cl in clusters.iter_mut() {
        bases.push(flexible_subspace(&ab, cl)?);
        left.push(invariant_subspace(&at_t, cl)?);
    }
    if n_zero > 0 {
        bases.insert(0, rigid_subspace(&ab, n_zero, &left)?);
    }
    let mut t = DMatrix::zeros(n, n);
    let mut offsets = Vec::with_capacity(bases.len());
    let mut col = 0;
    for s in &bases {
        t.columns_mut(col, s.ncols()).copy_from(s);
        offsets.push((col, s.ncols()));
        col += s.ncols();
    }
    let lu = t.clone().lu();
    let unseparable = || {
        PlantModelError::new(
            "A",
            R::Unseparable(
                "its invariant subspaces could not be separated (eigenvalues repeated to nearly \
                 the clustering tolerance)"
                    .into(),
            ),
        )
    };
    let at = lu.solve(&(&ab * &t)).ok_or_else(unseparable)?;
    let bt = lu.solve(&bb).ok_or_else(unseparable)?;
    let ct = &cb * &t;
    let mut off = at.clone();
    for &(o, len) in &offsets {
        off.view_mut((o, o), (len, len)).fill(0.0);
    }
    if off.amax().is_nan() || off.amax() > SEPARATION_TOL * at.amax() {
        return Err(unseparable());
    }
    let floor_b = NOISE_FLOOR * bt.norm();
    let floor_c = NOISE_FLOOR * ct.norm();

    let mut omega = Vec::new();
    let mut zeta = Vec::new();
    let mut phi_a: Vec<Vec<f64>> = Vec::new();
    let mut phi_s: Vec<Vec<f64>> = Vec::new();
    let mut blocks = offsets.iter();
    if n_zero > 0 {
        let &(o, len) = blocks.next().ok_or_else(unseparable)?;
        let ar = at.view((o, o), (len, len)).into_owned();
        let br = bt.rows(o, len).into_owned();
        let cr = ct.columns(o, len).into_owned();
        let r = len / 2;
        let reach = &ar * &br;
        let seen = &cr * &ar;
        if rank(&reach, floor_b * ar.norm()) < r {
            return Err(PlantModelError::new("B", R::UncontrollableRigidMode));
        }
        if rank(&seen, floor_c * ar.norm()) < r {
            return Err(PlantModelError::new("C", R::UnobservableRigidMode));
        }
        if (&cr * &br).norm() > STRUCTURE_TOL * cr.norm() * br.norm() {
            return Err(PlantModelError::new(
                "C",
                R::VelocityOutput { frequency_hz: 0.0 },
            ));
        }
        let res = &cr * &ar * &br;
        for (u, v) in split_residue(&res, r)? {
            omega.push(0.0);
            zeta.push(0.0);
            phi_s.push(u);
            phi_a.push(v);
        }
    }
    // Clusters with their refined frequencies; sort keeps the Schur order on ties.
    let mut flex: Vec<(f64, f64, Vec<ModeGains>)> = Vec::new();
    for (cl, &(o, len)) in clusters.iter().zip(blocks) {
        let k = cl.multiplicity;
        let ar = at.view((o, o), (len, len)).into_owned();
        let br = bt.rows(o, len).into_owned();
        let cr = ct.columns(o, len).into_owned();
        let (w, z) = refine(&ar, k);
        if z < -UNSTABLE_TOL {
            return Err(PlantModelError::new(
                "A",
                R::Unstable {
                    re: -z * w,
                    im: w * (1.0 - z * z).max(0.0).sqrt(),
                },
            ));
        }
        if w <= 0.0 || z >= 1.0 {
            return Err(PlantModelError::new("A", R::RealEigenvalue(-z * w)));
        }
        let z = z.max(0.0);
        let f_hz = w / (2.0 * std::f64::consts::PI);
        let reached = br.norm() > floor_b;
        let seen = cr.norm() > floor_c;
        if reached && rank(&br, floor_b) > k {
            return Err(PlantModelError::new(
                "B",
                R::InputNotForce { frequency_hz: f_hz },
            ));
        }
        if reached && seen && (&cr * &br).norm() > STRUCTURE_TOL * cr.norm() * br.norm() {
            return Err(PlantModelError::new(
                "C",
                R::VelocityOutput { frequency_hz: f_hz },
            ));
        }
        let modes = if reached && seen {
            let shifted = &ar + DMatrix::identity(len, len) * (2.0 * z * w);
            split_residue(&(&cr * shifted * &br), k)?
        } else {
            vec![(vec![0.0; p], vec![0.0; m]); k]
        };
        flex.push((w, z, modes));
    }
    flex.sort_by(|x, y| x.0.total_cmp(&y.0));
    for (w, z, modes) in flex {
        for (u, v) in modes {
            omega.push(w);
            zeta.push(z);
            phi_s.push(u);
            phi_a.push(v);
        }
    }
    let modes = omega.len();
    let mut pa = DMatrix::zeros(modes, m);
    let mut ps = DMatrix::zeros(p, modes);
    for i in 0..modes {
        let sign = sign_of(&phi_a[i], &phi_s[i]);
        for (j, v) in phi_a[i].iter().enumerate() {
            pa[(i, j)] = sign * v;
        }
        for (j, v) in phi_s[i].iter().enumerate() {
            ps[(j, i)] = sign * v;
        }
    }
    ModalModel::new(omega, zeta, pa, ps).map_err(|e| PlantModelError::new("A", R::Model(e)))
}

/// Counts the zero eigenvalues and clusters the complex pairs (upper half
/// plane, sorted by |λ|), refusing real nonzero and unstable eigenvalues.
fn classify(eig: &[Complex<f64>], size: f64) -> Result<(usize, Vec<Cluster>), PlantModelError> {
    let zero = ZERO_EIGENVALUE_TOL * size;
    let mut n_zero = 0;
    let mut upper: Vec<Complex<f64>> = Vec::new();
    let mut lower = 0;
    for &l in eig {
        let r = l.norm();
        if r <= zero {
            n_zero += 1;
        } else if l.re > UNSTABLE_TOL * r {
            return Err(PlantModelError::new(
                "A",
                R::Unstable { re: l.re, im: l.im },
            ));
        } else if l.im.abs() <= REAL_EIGENVALUE_TOL * r {
            return Err(PlantModelError::new("A", R::RealEigenvalue(l.re)));
        } else if l.im > 0.0 {
            upper.push(l);
        } else {
            lower += 1;
        }
    }
    if lower != upper.len() {
        return Err(PlantModelError::new(
            "A",
            R::Unseparable("its complex eigenvalues do not pair up".into()),
        ));
    }
    upper.sort_by(|x, y| x.norm().total_cmp(&y.norm()).then(x.im.total_cmp(&y.im)));
    let mut clusters: Vec<(Complex<f64>, Vec<Complex<f64>>)> = Vec::new();
    for l in upper {
        match clusters.last_mut() {
            Some((first, members)) if (l - *first).norm() <= CLUSTER_TOL * first.norm() => {
                members.push(l)
            }
            _ => clusters.push((l, vec![l])),
        }
    }
    let clusters = clusters
        .into_iter()
        .map(|(_, members)| {
            let k = members.len();
            let mean = members.iter().sum::<Complex<f64>>() / k as f64;
            Cluster {
                multiplicity: k,
                sigma: mean.re,
                abs2: mean.norm_sqr(),
            }
        })
        .collect();
    Ok((n_zero, clusters))
}

/// S₀, the invariant subspace of the zero eigenvalues, after checking that
/// they are 2×2 Jordan pairs (dim ker A = n_zero/2, dim ker A² = n_zero).
/// S₀ is taken as the orthogonal complement of the flexible clusters' left
/// invariant subspaces (those of Aᵀ): that is exactly the right invariant
/// subspace of the remaining eigenvalues, and it is computed from the
/// well-separated flexible eigenvalues, where null(A²) would carry the
/// rounding of the product A·A (ε‖A‖², large for a non-normal A).
fn rigid_subspace(
    a: &DMatrix<f64>,
    n_zero: usize,
    left: &[DMatrix<f64>],
) -> Result<DMatrix<f64>, PlantModelError> {
    let n = a.nrows();
    let norm = a.norm();
    let (s1, _) = svd_ascending(a)?;
    let kernel_dim = s1.iter().filter(|&&s| s <= KERNEL_TOL * norm).count();
    let refuse = || {
        PlantModelError::new(
            "A",
            R::NotRigidBodyIntegrator {
                zero_eigenvalues: n_zero,
                kernel_dim,
            },
        )
    };
    if !n_zero.is_multiple_of(2) || kernel_dim != n_zero / 2 {
        return Err(refuse());
    }
    let (s2, _) = svd_ascending(&(a * a))?;
    if s2[n_zero - 1] > KERNEL_TOL * norm * norm {
        return Err(refuse());
    }
    // Null space of Wᵀ (W: the left flexible bases side by side), padded to
    // a square matrix so that the SVD gives all n right singular vectors.
    let mut wt = DMatrix::zeros(n, n);
    let mut row = 0;
    for w in left {
        wt.view_mut((row, 0), (w.ncols(), n))
            .copy_from(&w.transpose());
        row += w.ncols();
    }
    let (_, v) = svd_ascending(&wt)?;
    Ok(v.columns(0, n_zero).into_owned())
}

/// The real invariant subspace of a flexible cluster, computed twice: the
/// second time with σ and |λ|² from the block the first subspace gives
/// (Schur's eigenvalues of a repeated pair are averaged; the block's traces
/// are more accurate).
fn flexible_subspace(a: &DMatrix<f64>, cl: &mut Cluster) -> Result<DMatrix<f64>, PlantModelError> {
    let basis = invariant_subspace(a, cl)?;
    let block = basis.transpose() * a * &basis;
    let k = cl.multiplicity as f64;
    let sigma = block.trace() / (2.0 * k);
    let abs2 = 2.0 * sigma * sigma - (&block * &block).trace() / (2.0 * k);
    if abs2 > sigma * sigma {
        cl.sigma = sigma;
        cl.abs2 = abs2;
    }
    invariant_subspace(a, cl)
}

/// Orthonormal real basis (n × 2k) of span{Re v, Im v : (A − λI) v = 0}, the
/// null space taken as the k right singular vectors of A − λI with the
/// smallest singular values (rounding leaves about ε‖A‖ on them; a Jordan
/// block at λ leaves fewer than k near zero).
fn invariant_subspace(a: &DMatrix<f64>, cl: &Cluster) -> Result<DMatrix<f64>, PlantModelError> {
    let n = a.nrows();
    let k = cl.multiplicity;
    let lambda = Complex::new(cl.sigma, (cl.abs2 - cl.sigma * cl.sigma).max(0.0).sqrt());
    let shifted =
        a.map(|v| Complex::new(v, 0.0)) - DMatrix::<Complex<f64>>::identity(n, n) * lambda;
    let svd = shifted
        .try_svd(false, true, f64::EPSILON, 1000 * n)
        .ok_or(PlantModelError::new("A", R::NoConvergence("complex SVD")))?;
    let v_t = svd
        .v_t
        .ok_or(PlantModelError::new("A", R::NoConvergence("complex SVD")))?;
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&i, &j| svd.singular_values[i].total_cmp(&svd.singular_values[j]));
    if svd.singular_values[order[k - 1]] > NULL_TOL * a.norm() {
        return Err(PlantModelError::new(
            "A",
            R::DefectiveEigenvalue {
                frequency_hz: cl.frequency_hz(),
            },
        ));
    }
    let mut parts = DMatrix::zeros(n, 2 * k);
    for (c, &i) in order.iter().take(k).enumerate() {
        // Rows of V^H are the conjugated singular vectors.
        for r in 0..n {
            let v = v_t[(i, r)].conj();
            parts[(r, 2 * c)] = v.re;
            parts[(r, 2 * c + 1)] = v.im;
        }
    }
    let svd = parts
        .try_svd(true, false, f64::EPSILON, 1000 * n)
        .ok_or(PlantModelError::new("A", R::NoConvergence("SVD")))?;
    let u = svd
        .u
        .ok_or(PlantModelError::new("A", R::NoConvergence("SVD")))?;
    Ok(u.columns(0, 2 * k).into_owned())
}

/// ω and ζ of a block with Ā² − 2σĀ + |λ|²I = 0 (all eigenvalues σ ± iω_d):
/// tr Ā = 2kσ, tr Ā² = 2k(σ² − ω_d²).
fn refine(block: &DMatrix<f64>, k: usize) -> (f64, f64) {
    let k = k as f64;
    let sigma = block.trace() / (2.0 * k);
    let abs2 = 2.0 * sigma * sigma - (block * block).trace() / (2.0 * k);
    let w = abs2.max(0.0).sqrt();
    let z = if w > 0.0 { -sigma / w } else { f64::INFINITY };
    (w, z)
}

/// Singular values ascending and the matching right singular vectors as
/// columns.
fn svd_ascending(m: &DMatrix<f64>) -> Result<(Vec<f64>, DMatrix<f64>), PlantModelError> {
    let n = m.ncols();
    let svd = m
        .clone()
        .try_svd(false, true, f64::EPSILON, 1000 * n.max(m.nrows()).max(1))
        .ok_or(PlantModelError::new("A", R::NoConvergence("SVD")))?;
    let v_t = svd
        .v_t
        .ok_or(PlantModelError::new("A", R::NoConvergence("SVD")))?;
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&i, &j| svd.singular_values[i].total_cmp(&svd.singular_values[j]));
    let s = order.iter().map(|&i| svd.singular_values[i]).collect();
    let mut v = DMatrix::zeros(n, order.len());
    for (col, &i) in order.iter().enumerate() {
        v.column_mut(col).copy_from(&v_t.row(i).transpose());
    }
    Ok((s, v))
}

/// Rank: singular values above RANK_TOL of the largest and above `floor`.
fn rank(m: &DMatrix<f64>, floor: f64) -> usize {
    if m.is_empty() {
        return 0;
    }
    let s = m.singular_values();
    let smax = s.max();
    s.iter()
        .filter(|&&v| v > RANK_TOL * smax && v > floor)
        .count()
}

/// The residue R (p×m) as `k` rank-one terms (φ_s, φ_a), largest first;
/// missing terms (rank < k) are zeros.
fn split_residue(res: &DMatrix<f64>, k: usize) -> Result<Vec<ModeGains>, PlantModelError> {
    let (p, m) = res.shape();
    let mut out = vec![(vec![0.0; p], vec![0.0; m]); k];
    if res.is_empty() {
        return Ok(out);
    }
    let svd = res
        .clone()
        .try_svd(true, true, f64::EPSILON, 1000 * p.max(m))
        .ok_or(PlantModelError::new(
            "A",
            R::NoConvergence("SVD of a residue"),
        ))?;
    let (u, v_t) = match (svd.u, svd.v_t) {
        (Some(u), Some(v_t)) => (u, v_t),
        _ => return Err(PlantModelError::new("A", R::NoConvergence("SVD"))),
    };
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&i, &j| svd.singular_values[j].total_cmp(&svd.singular_values[i]));
    for (slot, &i) in out.iter_mut().zip(order.iter()) {
        let g = svd.singular_values[i].sqrt();
        slot.0 = u.column(i).iter().map(|x| x * g).collect();
        slot.1 = v_t.row(i).iter().map(|x| x * g).collect();
    }
    Ok(out)
}

/// The sign convention of [`crate::modal`]: φ_a at the first input positive
/// where it is not negligible, else the largest φ_a entry, else φ_s's.
fn sign_of(phi_a: &[f64], phi_s: &[f64]) -> f64 {
    let largest = |v: &[f64]| {
        v.iter()
            .copied()
            .fold(0.0f64, |acc, x| if x.abs() > acc.abs() { x } else { acc })
    };
    let amax = largest(phi_a);
    let reference = match phi_a.first() {
        Some(&g) if g.abs() > 1e-9 * amax.abs() => g,
        _ if amax != 0.0 => amax,
        _ => largest(phi_s),
    };
    if reference < 0.0 { -1.0 } else { 1.0 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::block_diag;
    use crate::plant_model_error::PlantModelReason;

    /// [[0, 1], [−ω², −2ζω]] (type 1, docs/control.md (2.9)).
    fn mode(w: f64, z: f64) -> DMatrix<f64> {
        DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -w * w, -2.0 * z * w])
    }

    fn rigid() -> DMatrix<f64> {
        DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0])
    }

    /// A rigid mode and a 50 Hz mode, one force (gains 0.3 and 0.5), one
    /// position output (gains 0.3 and −0.4).
    fn model() -> (DMatrix<f64>, DMatrix<f64>, DMatrix<f64>) {
        let w = 2.0 * std::f64::consts::PI * 50.0;
        let a = block_diag(&[&rigid(), &mode(w, 0.02)]);
        let b = DMatrix::from_column_slice(4, 1, &[0.0, 0.3, 0.0, 0.5]);
        let c = DMatrix::from_row_slice(1, 4, &[0.3, 0.0, -0.4, 0.0]);
        (a, b, c)
    }

    fn reason(
        a: &DMatrix<f64>,
        b: &DMatrix<f64>,
        c: &DMatrix<f64>,
    ) -> (&'static str, PlantModelReason) {
        let e = modal_from_state_space(a, b, c, None).unwrap_err();
        (e.array, e.reason)
    }

    #[test]
    fn modal_blocks_come_back() {
        let (a, b, c) = model();
        let zeros = DMatrix::zeros(1, 1);
        let m = modal_from_state_space(&a, &b, &c, Some(&zeros)).unwrap();
        assert_eq!(m.n_rigid, 1);
        assert_eq!(m.omega[0], 0.0);
        assert!((m.frequencies_hz()[1] - 50.0).abs() < 1e-12);
        assert!((m.zeta[1] - 0.02).abs() < 1e-14);
        assert!((m.phi_s[(0, 0)] * m.phi_a[(0, 0)] - 0.09).abs() < 1e-14);
        assert!((m.phi_s[(0, 1)] * m.phi_a[(1, 0)] + 0.2).abs() < 1e-14);
        // Normalisation and sign.
        assert!((m.phi_a[(1, 0)] - 0.2f64.sqrt()).abs() < 1e-14);
        assert!((m.phi_s[(0, 1)] + 0.2f64.sqrt()).abs() < 1e-14);
    }

    #[test]
    fn refuses_what_is_not_a_structural_model() {
        let (a, b, c) = model();
        let w = 2.0 * std::f64::consts::PI * 50.0;
        // First-order dynamics (an actuator lag).
        let lag = block_diag(&[&a, &DMatrix::from_element(1, 1, -100.0)]);
        let b5 = DMatrix::from_column_slice(5, 1, &[0.0, 0.3, 0.0, 0.5, 1.0]);
        let c5 = DMatrix::from_row_slice(1, 5, &[0.3, 0.0, -0.4, 0.0, 0.0]);
        assert!(matches!(
            reason(&lag, &b5, &c5),
            ("A", PlantModelReason::RealEigenvalue(l)) if (l + 100.0).abs() < 1e-9
        ));
        // Overdamped (ζ = 1.5): real eigenvalues.
        let over = block_diag(&[&rigid(), &mode(w, 1.5)]);
        assert!(matches!(
            reason(&over, &b, &c),
            ("A", PlantModelReason::RealEigenvalue(_))
        ));
        // Negative damping: unstable.
        let unstable = block_diag(&[&rigid(), &mode(w, -0.01)]);
        let (array, r) = reason(&unstable, &b, &c);
        assert_eq!(array, "A");
        assert!(matches!(r, PlantModelReason::Unstable { re, .. } if re > 0.0));
        // A single integrator; two of them; a chain of four.
        let single = block_diag(&[&DMatrix::zeros(1, 1), &mode(w, 0.02)]);
        let b3 = DMatrix::from_column_slice(3, 1, &[1.0, 0.0, 0.5]);
        let c3 = DMatrix::from_row_slice(1, 3, &[1.0, -0.4, 0.0]);
        let e = modal_from_state_space(&single, &b3, &c3, None).unwrap_err();
        assert_eq!(
            e.reason,
            PlantModelReason::NotRigidBodyIntegrator {
                zero_eigenvalues: 1,
                kernel_dim: 1
            }
        );
        assert!(e.to_string().contains("single integrator"));
        let two = block_diag(&[&DMatrix::zeros(2, 2), &mode(w, 0.02)]);
        assert_eq!(
            reason(&two, &b, &c).1,
            PlantModelReason::NotRigidBodyIntegrator {
                zero_eigenvalues: 2,
                kernel_dim: 2
            }
        );
        let mut four = DMatrix::zeros(4, 4);
        for i in 0..3 {
            four[(i, i + 1)] = 1.0;
        }
        let b4 = DMatrix::from_column_slice(4, 1, &[0.0, 0.0, 0.0, 1.0]);
        let c4 = DMatrix::from_row_slice(1, 4, &[1.0, 0.0, 0.0, 0.0]);
        assert_eq!(
            reason(&four, &b4, &c4).1,
            PlantModelReason::NotRigidBodyIntegrator {
                zero_eigenvalues: 4,
                kernel_dim: 1
            }
        );
        // An input of rank 2 into the flexible mode.
        let b2 = DMatrix::from_row_slice(4, 2, &[0.0, 0.0, 0.3, 0.0, 0.0, 1.0, 0.5, 0.0]);
        assert!(matches!(
            reason(&a, &b2, &c),
            ("B", PlantModelReason::InputNotForce { frequency_hz }) if (frequency_hz - 50.0).abs() < 1e-9
        ));
        // A velocity output of the flexible mode, of the rigid mode.
        let cv = DMatrix::from_row_slice(1, 4, &[0.3, 0.0, -0.4, 0.01]);
        assert!(matches!(
            reason(&a, &b, &cv),
            ("C", PlantModelReason::VelocityOutput { .. })
        ));
        let cv = DMatrix::from_row_slice(1, 4, &[0.3, 0.2, -0.4, 0.0]);
        assert_eq!(
            reason(&a, &b, &cv),
            ("C", PlantModelReason::VelocityOutput { frequency_hz: 0.0 })
        );
        // Rigid mode not reached, not seen.
        let bu = DMatrix::from_column_slice(4, 1, &[0.0, 0.0, 0.0, 0.5]);
        assert_eq!(
            reason(&a, &bu, &c),
            ("B", PlantModelReason::UncontrollableRigidMode)
        );
        let cu = DMatrix::from_row_slice(1, 4, &[0.0, 0.0, -0.4, 0.0]);
        assert_eq!(
            reason(&a, &b, &cu),
            ("C", PlantModelReason::UnobservableRigidMode)
        );
        // A repeated pair with a Jordan block.
        let mut jordan = block_diag(&[&mode(w, 0.02), &mode(w, 0.02)]);
        jordan[(0, 2)] = 1.0;
        jordan[(1, 3)] = 1.0;
        let bj = DMatrix::from_column_slice(4, 1, &[0.0, 0.0, 0.0, 1.0]);
        let cj = DMatrix::from_row_slice(1, 4, &[1.0, 0.0, 0.0, 0.0]);
        let (array, r) = reason(&jordan, &bj, &cj);
        assert_eq!(array, "A");
        assert!(
            matches!(r, PlantModelReason::DefectiveEigenvalue { .. }),
            "{r:?}"
        );
    }

    #[test]
    fn refuses_bad_arrays() {
        let (a, b, c) = model();
        let d = DMatrix::from_element(1, 1, 1e-3);
        let e = modal_from_state_space(&a, &b, &c, Some(&d)).unwrap_err();
        assert_eq!(e, PlantModelError::new("D", PlantModelReason::Feedthrough));
        assert!(e.to_string().starts_with("D: is nonzero"));
        let d = DMatrix::zeros(2, 1);
        let e = modal_from_state_space(&a, &b, &c, Some(&d)).unwrap_err();
        assert_eq!(e.array, "D");
        let mut bad = a.clone();
        bad[(3, 2)] = f64::INFINITY;
        assert_eq!(reason(&bad, &b, &c), ("A", PlantModelReason::NonFinite));
        assert_eq!(reason(&a, &b.rows(0, 3).into(), &c).0, "B");
        assert_eq!(reason(&a, &b, &c.columns(0, 3).into()).0, "C");
        assert_eq!(reason(&a.columns(0, 3).into(), &b, &c).0, "A");
    }

    #[test]
    fn repeated_frequencies_and_an_unreached_mode() {
        // Two equal 50 Hz modes seen by two sensors from two forces, and a
        // 80 Hz mode no force reaches.
        let w = 2.0 * std::f64::consts::PI * 50.0;
        let a = block_diag(&[&mode(w, 0.01), &mode(w, 0.01), &mode(1.6 * w, 0.01)]);
        let mut b = DMatrix::zeros(6, 2);
        b[(1, 0)] = 1.0;
        b[(1, 1)] = 0.5;
        b[(3, 1)] = 2.0;
        let mut c = DMatrix::zeros(2, 6);
        c[(0, 0)] = 1.0;
        c[(1, 2)] = 1.0;
        c[(1, 0)] = 0.3;
        c[(0, 4)] = 0.7;
        let m = modal_from_state_space(&a, &b, &c, None).unwrap();
        assert_eq!(m.modes(), 3);
        assert!((m.omega[1] / m.omega[0] - 1.0).abs() < 1e-12);
        let sum = m.phi_s.column(0) * m.phi_a.row(0) + m.phi_s.column(1) * m.phi_a.row(1);
        let want = c.select_columns(&[0, 2]) * b.select_rows(&[1, 3]);
        assert!((sum - &want).amax() < 1e-12 * want.amax());
        assert_eq!(m.phi_a.row(2).amax(), 0.0);
        assert_eq!(m.phi_s.column(2).amax(), 0.0);
    }
}
