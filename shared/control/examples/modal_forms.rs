//! The thesis chain (docs/control.md §1.3) entered in each form a user
//! brings, brought back to modal form, against the built-in model: per mode
//! the frequency, ζ and the input–output gain φ_s φ_aᵀ (7 outputs × 1
//! input), and how many significant digits of each agree.
//!
//! Run: `cargo run -p flexloop-control --example modal_forms`.

use flexloop_control::discretise::zoh;
use flexloop_control::lumped_network::{Attach, lumped_network};
use flexloop_control::modal::{ModalDamping, ModalModel};
use flexloop_control::models::{
    CHAIN_K, CHAIN_KA, CHAIN_MA, CHAIN_MI, CHAIN_ZETA, TS_10KHZ, thesis_chain, thesis_chain_modal,
};
use flexloop_control::real_modal_form::modal_from_state_space;
use flexloop_control::second_order::modal_from_second_order;
use flexloop_control::zoh_inverse::continuous_from_zoh;
use nalgebra::{DMatrix, DVector};
use std::error::Error;

/// Significant digits of `got` agreeing with `want`, 16 when equal.
fn digits(err: f64) -> f64 {
    if err == 0.0 {
        16.0
    } else {
        (-err.log10()).clamp(0.0, 16.0)
    }
}

fn main() -> Result<(), Box<dyn Error>> {
    let want = thesis_chain_modal()?;
    let nodal = thesis_chain();
    let (m, k, b, c) = (
        &nodal.mass,
        &nodal.stiffness,
        &nodal.actuators,
        &nodal.sensors,
    );
    let phi = want.shapes.clone().ok_or("built-in chain has shapes")?;
    let n = m.nrows();
    // D = Φ⁻ᵀ diag(2ζω) Φ⁻¹ = M Φ diag(2ζω) Φᵀ M.
    let z = DMatrix::from_diagonal(&DVector::from_iterator(
        n,
        (0..n).map(|i| 2.0 * want.zeta[i] * want.omega[i]),
    ));
    let d = m * &phi * z * phi.transpose() * m;

    let mut forms: Vec<(&str, ModalModel)> = Vec::new();
    let mut masses = vec![CHAIN_MI; 8];
    masses[0] = CHAIN_MA;
    let springs: Vec<_> = (0..7)
        .map(|i| (i, Some(i + 1), if i == 0 { CHAIN_KA } else { CHAIN_K }))
        .collect();
    let positions: Vec<_> = (1..=7).map(Attach::At).collect();
    let net = lumped_network(&masses, &springs, &[], &[Attach::At(0)], &positions)?;
    let zeta = Some(ModalDamping::Uniform(CHAIN_ZETA));
    forms.push((
        "lumped network, modal ζ",
        modal_from_second_order(&net.m, &net.k, None, &net.b, &net.c, zeta)?,
    ));
    forms.push((
        "M, K, D, B, C",
        modal_from_second_order(m, k, Some(&d), b, c, None)?,
    ));
    // x = (q, q̇): A = [[0, I], [−M⁻¹K, −M⁻¹D]], B = [0; M⁻¹B], C = [C, 0].
    let minv = m.clone().try_inverse().ok_or("M is invertible")?;
    let mut a = DMatrix::zeros(2 * n, 2 * n);
    a.view_mut((0, n), (n, n))
        .copy_from(&DMatrix::identity(n, n));
    a.view_mut((n, 0), (n, n)).copy_from(&(-&minv * k));
    a.view_mut((n, n), (n, n)).copy_from(&(-&minv * &d));
    let mut bs = DMatrix::zeros(2 * n, 1);
    bs.view_mut((n, 0), (n, 1)).copy_from(&(&minv * b));
    let mut cs = DMatrix::zeros(7, 2 * n);
    cs.view_mut((0, 0), (7, n)).copy_from(c);
    forms.push((
        "A, B, C (q, q̇)",
        modal_from_state_space(&a, &bs, &cs, None)?,
    ));
    let phys = flexloop_control::continuous::ContinuousStateSpace::new(
        a.clone(),
        bs.clone(),
        cs.clone(),
        DMatrix::zeros(7, 1),
    )?;
    let disc = zoh(&phys, TS_10KHZ)?;
    let (ac, bc) = continuous_from_zoh(&disc.a, &disc.b, TS_10KHZ)?;
    forms.push((
        "A_d, B_d, C at 10 kHz",
        modal_from_state_space(&ac, &bc, &cs, None)?,
    ));

    println!("built-in thesis chain vs each form: digits that agree (16 = identical)");
    println!(
        "{:>4} {:>10} | {:^23} | {:^23} | {:^23} | {:^23}",
        "mode", "f [Hz]", forms[0].0, forms[1].0, forms[2].0, forms[3].0
    );
    println!(
        "{:>4} {:>10} |{}",
        "",
        "",
        "    f     ζ   φ_s φ_aᵀ  |".repeat(forms.len())
    );
    for i in 0..want.modes() {
        let mut line = format!("{i:>4} {:>10.4} |", want.frequencies_hz()[i]);
        for (_, got) in &forms {
            let f = if want.omega[i] == 0.0 {
                if got.omega[i] == 0.0 { 0.0 } else { 1.0 }
            } else {
                (got.omega[i] / want.omega[i] - 1.0).abs()
            };
            let zeta = (got.zeta[i] - want.zeta[i]).abs() / CHAIN_ZETA;
            let pg = got.phi_s.column(i) * got.phi_a.row(i);
            let pw = want.phi_s.column(i) * want.phi_a.row(i);
            let p = (&pg - &pw).norm() / pw.norm();
            line += &format!(
                " {:>5.1} {:>5.1} {:>8.1}   |",
                digits(f),
                digits(zeta),
                digits(p)
            );
        }
        println!("{line}");
    }
    println!(
        "ζ digits are relative to ζ = {CHAIN_ZETA}; φ_s φ_aᵀ is the 7×1 gain of the mode \
         (its norm relative), the quantity independent of normalisation."
    );
    Ok(())
}
