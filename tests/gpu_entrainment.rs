//! `physics.entrainment` (sim::forces::entrainment) on the GPU: the pass against its f64
//! mirror, and what it keeps: the clear air takes what the clouds give up, so the sums of
//! m s_l and m q_t are those before the pass.
mod harness;

use nimbus::config::ShotConfig;
use nimbus::ground::ParticleState;
use nimbus::sim::forces::entrainment::{EntrainmentStage, EntrainmentTable};
use nimbus::sim::reference::entrainment::apply_entrainment;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn shot() -> ShotConfig {
    serde_saphyr::from_str(
        "shot: e\noutput: {frames: {start: 1, end: 2}, frame_seconds: 60, substeps: 4}\n\
         domain: {size: [1000.0, 3000.0, 1000.0], spacing: 50.0}\n\
         physics: {entrainment: 2.0e-3}\n",
    )
    .unwrap()
}

/// A random position in the box of [`shot`].
fn random_position(rng: &mut ChaCha8Rng) -> [f32; 4] {
    [
        rng.random_range(0.0..1000.0),
        rng.random_range(0.0..3000.0),
        rng.random_range(0.0..1000.0),
        0.0,
    ]
}

/// Random particles over the whole box: a third cloudy, rising and sinking at up to 3 m/s, a
/// fifth of half mass; with `dry`, every tenth clear one with almost no vapor and the clouds
/// drier than the clear air.
fn random_state(seed: u64, dry: bool) -> ParticleState {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = 3000;
    let mut st = ParticleState::default();
    for k in 0..n {
        st.pos.push(random_position(&mut rng));
        st.vel.push([0.0, rng.random_range(-3.0..3.0), 0.0, 0.0]);
        let cloudy = k % 3 == 0;
        // with `dry`, clouds drier than the clear air, which then gives them vapor: the
        // nearly dry clear particles run out
        let v = if dry && !cloudy && k % 10 == 1 {
            1.0e-8
        } else if dry && cloudy {
            rng.random_range(0.002..0.008)
        } else {
            rng.random_range(0.004..0.02)
        };
        let w = if cloudy {
            rng.random_range(1.0e-6..1.0e-3)
        } else {
            0.0
        };
        st.thermo.push([rng.random_range(280.0..305.0), v, w, 0.0]);
        st.info.push([k as u32, (k % 5 == 0) as u32]);
    }
    st
}

/// Mass-weighted sums (relative masses) of s_l and q_t, over the cloudy particles of `before`
/// and over the clear ones, in `s`.
fn sums(cfg: &ShotConfig, before: &ParticleState, s: &ParticleState) -> [[f64; 2]; 2] {
    let p = &cfg.physics;
    let mut out = [[0.0; 2]; 2];
    for i in 0..s.len() {
        let m = (-(s.info[i][1] as f64)).exp2();
        let th = s.thermo[i].map(|v| v as f64);
        let y = s.pos[i][1] as f64;
        let part = (before.thermo[i][2] > 0.0) as usize;
        out[part][0] += m * (th[0] + p.adiabatic_lapse_rate * y - p.latent_heat * th[2]);
        out[part][1] += m * (th[1] + th[2]);
    }
    out
}

/// One pass over random particles against `apply_entrainment`: T to 2e-4 K (an f32 ulp at
/// 300 K is 3e-5 K, and the clear air's T is its s_l less Gamma_d y), v to eight f32 ulps of
/// 0.03 (what it adds up), w to four ulps of itself.
#[test]
fn apply_entrainment_matches_the_mirror() {
    let cfg = shot();
    let seed = harness::fresh_seed();
    let state = random_state(seed, true);
    let (ctx, b, stage) = harness::stage_over::<EntrainmentStage>(&cfg, &state);
    let table = EntrainmentTable::of_state(&cfg, &state, 60.0);
    let params = table.params(cfg.physics.adiabatic_lapse_rate);
    let (out, _) = harness::run_gpu(&ctx, &b, |rec, live| stage.apply_with(rec, live, &params));

    let pos: Vec<[f64; 3]> = state.pos.iter().map(harness::v3).collect();
    let vel: Vec<[f64; 3]> = state.vel.iter().map(harness::v3).collect();
    let mut th: Vec<[f64; 4]> = state.thermo.iter().map(|t| t.map(|v| v as f64)).collect();
    apply_entrainment(&params, &pos, &vel, &mut th);
    let eps = f32::EPSILON as f64;
    let (mut diluted, mut floored) = (0.0f64, 0);
    for (i, (g, m)) in out.thermo.iter().zip(&th).enumerate() {
        assert!(
            (g[0] as f64 - m[0]).abs() < 2e-4,
            "seed {seed}: T {i}: {} vs {}",
            g[0],
            m[0]
        );
        assert!(
            (g[1] as f64 - m[1]).abs() <= 8.0 * eps * 0.03,
            "seed {seed}: v {i}: {} vs {}",
            g[1],
            m[1]
        );
        assert!(
            (g[2] as f64 - m[2]).abs() <= 4.0 * eps * state.thermo[i][2] as f64,
            "seed {seed}: w {i}: {} vs {}",
            g[2],
            m[2]
        );
        let w0 = state.thermo[i][2] as f64;
        if w0 > 0.0 {
            diluted = diluted.max(1.0 - m[2] / w0);
        }
        floored += (m[1] == 0.0) as usize;
    }
    // the pass did something to compare: a cloud rising at 3 m/s keeps exp(-0.36) of its water
    assert!(diluted > 0.25, "largest dilution {diluted}");
    assert!(floored > 0, "no clear particle ran out of vapor");
}

/// On the GPU, over random particles without the vapor floor: the clouds lose what the table
/// says they give up (sum of m r (phi - phi_env)), and the clear air gains it, in s_l and q_t,
/// to 1e-4 of it (the f32 rounding of 3000 temperatures of 300 K is about 2e-3 K in all).
#[test]
fn the_clear_air_takes_what_the_clouds_give_up() {
    let cfg = shot();
    let seed = harness::fresh_seed();
    let state = random_state(seed, false);
    let (ctx, b, stage) = harness::stage_over::<EntrainmentStage>(&cfg, &state);
    let table = EntrainmentTable::of_state(&cfg, &state, 60.0);
    let params = table.params(cfg.physics.adiabatic_lapse_rate);
    let (out, _) = harness::run_gpu(&ctx, &b, |rec, live| stage.apply_with(rec, live, &params));
    let (before, after) = (sums(&cfg, &state, &state), sums(&cfg, &state, &out));
    for (c, name, floor) in [(0, "s_l", 5e-3), (1, "q_t", 1e-9)] {
        let given = table.given[c];
        let lost = before[1][c] - after[1][c];
        let gained = after[0][c] - before[0][c];
        eprintln!("{name}: the table gives {given:.6e}, the clouds lost {lost:.6e}, the clear air gained {gained:.6e}");
        assert!(
            given.abs() > 100.0 * floor,
            "seed {seed}: {name}: nothing moved ({given})"
        );
        let tol = 1e-4 * given.abs() + floor;
        assert!(
            (lost - given).abs() < tol,
            "seed {seed}: {name}: lost {lost} vs {given}"
        );
        assert!(
            (gained - given).abs() < tol,
            "seed {seed}: {name}: gained {gained} vs {given}"
        );
    }
}

/// A gain below half an f32 ulp (a tenth of one, in T at 300 K and in v at 0.015) is not lost
/// to rounding: over 20 000 clear particles the GPU adds it on average (a plain f32 sum would
/// add nothing), to 10% (the draws' spread is 2%).
#[test]
fn a_gain_below_an_ulp_is_kept_on_average() {
    let cfg = shot();
    let seed = harness::fresh_seed();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = 20_000;
    let mut st = ParticleState::default();
    for k in 0..n {
        st.pos.push(random_position(&mut rng));
        st.vel.push([0.0; 4]);
        st.thermo.push([300.5, 0.015, 0.0, 0.0]);
        st.info.push([k as u32, 0]);
    }
    let (ctx, b, stage) = harness::stage_over::<EntrainmentStage>(&cfg, &st);
    let mut params = EntrainmentTable::of_state(&cfg, &st, 60.0).params(0.0098);
    let ulp = |x: f32| (f32::from_bits(x.to_bits() + 1) - x) as f64;
    let gain = [0.1 * ulp(300.5), 0.1 * ulp(0.015)];
    for row in params.gain.iter_mut() {
        *row = [gain[0] as f32, gain[1] as f32, 0.0, 0.0];
    }
    let (out, _) = harness::run_gpu(&ctx, &b, |rec, live| stage.apply_with(rec, live, &params));
    for (c, name) in [(0, "T"), (1, "v")] {
        let added: f64 = (0..n)
            .map(|i| out.thermo[i][c] as f64 - st.thermo[i][c] as f64)
            .sum();
        let want = n as f64 * gain[c];
        assert!(
            (added / want - 1.0).abs() < 0.1,
            "seed {seed}: {name}: added {added:e}, want {want:e}"
        );
    }
}
