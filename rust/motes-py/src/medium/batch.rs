//! The evaluated-mode batch calls of a discrete medium (`motes_core::render::discrete::batch`): numpy
//! arrays of rays, events and lanes in, numpy arrays out, the GIL released while the core works.

use super::PyDiscreteMedium;
use crate::convert::*;
use motes_core::render::discrete::{PhaseEvalLane, PhaseSampleLane};
use numpy::{IntoPyArray, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

#[pymethods]
impl PyDiscreteMedium {
    /// Next site per ray on (0, t_max): (t or NaN, optical depth walked before it); the events of
    /// lanes marked in `remember` are remembered at commit.
    fn sample_sites<'py>(
        &self,
        py: Python<'py>,
        origins: F32In,
        directions: F32In,
        t_max: F64In,
        remember: PyReadonlyArray1<'_, bool>,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>)> {
        let (o, d, tm, keep) = (
            vec3s(&origins, "origins")?,
            vec3s(&directions, "directions")?,
            t_max.as_slice()?.to_vec(),
            remember.as_slice()?.to_vec(),
        );
        if d.len() != o.len() || tm.len() != o.len() || keep.len() != o.len() {
            return Err(PyValueError::new_err(
                "origins, directions, t_max and remember must describe the same rays",
            ));
        }
        let res = py.detach(|| self.medium.sample_sites(&o, &d, &tm, &keep));
        let t: Vec<f64> = res.iter().map(|r| r.t.unwrap_or(f64::NAN)).collect();
        let tau: Vec<f64> = res.iter().map(|r| r.tau_before).collect();
        Ok((t.into_pyarray(py), tau.into_pyarray(py)))
    }

    /// Remember the last call's events at the positions `p` (where `active`), return albedo (n*channels).
    fn commit_events<'py>(
        &self,
        py: Python<'py>,
        p: F32In,
        active: PyReadonlyArray1<'_, bool>,
        lambda: F64In,
        channels: usize,
    ) -> PyResult<F64Out<'py>> {
        let (pp, act, lam) = (
            vec3s(&p, "p")?,
            active.as_slice()?.to_vec(),
            lambda.as_slice()?.to_vec(),
        );
        let out = py
            .detach(|| self.medium.commit_events(&pp, &act, &lam, channels))
            .map_err(to_py)?;
        Ok(out.into_pyarray(py))
    }

    /// Sample the phase function of the events at `p`: (wo n*3, weight n*channels, pdf n).
    #[allow(clippy::too_many_arguments)]
    fn phase_sample<'py>(
        &self,
        py: Python<'py>,
        p: F32In,
        wi: F32In,
        lambda: F64In,
        channels: usize,
        u1: F64In,
        u2: F64In,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>, F64Out<'py>)> {
        let (pp, a, lam, s1, s2) = (
            vec3s(&p, "p")?,
            vec3s(&wi, "wi")?,
            lambda.as_slice()?.to_vec(),
            u1.as_slice()?,
            u2.as_slice()?,
        );
        if a.len() != pp.len()
            || s1.len() != pp.len()
            || s2.len() != 2 * pp.len()
            || !per_lane(&lam, channels, pp.len())
        {
            return Err(PyValueError::new_err(
                "p, wi, u1, u2 and lambda must describe the same lanes",
            ));
        }
        let lanes: Vec<PhaseSampleLane> = pp
            .into_iter()
            .zip(a.into_iter().zip(s1.iter().copied().zip(pairs(s2))))
            .map(|(p, (wi, (u1, u2)))| PhaseSampleLane { p, wi, u1, u2 })
            .collect();
        let out = py.detach(|| self.medium.phase_sample(&lanes, &lam, channels));
        Ok(sampled(py, out))
    }

    /// Phase function of the events at `p`: (values n*channels, pdf n).
    fn phase_eval<'py>(
        &self,
        py: Python<'py>,
        p: F32In,
        wi: F32In,
        wo: F32In,
        lambda: F64In,
        channels: usize,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>)> {
        let (lanes, lam) = eval_lanes(&p, &wi, &wo, &lambda, channels)?;
        let (v, pdf) = py.detach(|| self.medium.phase_eval(&lanes, &lam, channels));
        Ok((v.into_pyarray(py), pdf.into_pyarray(py)))
    }

    /// Mueller elements of the events at `p` (polarised variants): (values n*channels*4, the elements
    /// F11, F12, F33, F34 of each channel; pdf n).
    fn phase_mueller<'py>(
        &self,
        py: Python<'py>,
        p: F32In,
        wi: F32In,
        wo: F32In,
        lambda: F64In,
        channels: usize,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>)> {
        let (lanes, lam) = eval_lanes(&p, &wi, &wo, &lambda, channels)?;
        let (v, pdf) = py
            .detach(|| self.medium.phase_mueller(&lanes, &lam, channels))
            .map_err(to_py)?;
        Ok((v.into_pyarray(py), pdf.into_pyarray(py)))
    }

    /// Whether the medium's grains polarise (its bins carry Mueller ratios).
    #[getter]
    fn polarizes(&self) -> bool {
        self.medium.polarizes()
    }

    /// Eq. 24 at points (f64 n*3): (sigma_s n*channels, Q = sigma_s f at cos θ = `mu`, n*channels).
    fn local_scattering<'py>(
        &self,
        py: Python<'py>,
        points: F64In,
        mu: F64In,
        lambda: F64In,
        channels: usize,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>)> {
        let pts = triples(points.as_slice()?);
        let (mu, lam) = (mu.as_slice()?.to_vec(), lambda.as_slice()?.to_vec());
        if mu.len() != pts.len()
            || points.len()? != 3 * pts.len()
            || channels == 0
            || !per_lane(&lam, channels, pts.len())
        {
            return Err(PyValueError::new_err("points (n, 3), mu (n) and lambda (channels or n*channels) must describe the same points"));
        }
        let (sg, q) = py.detach(|| self.medium.local_scattering(&pts, &mu, &lam, channels));
        Ok((sg.into_pyarray(py), q.into_pyarray(py)))
    }

    /// Sample the local mixture at points: (wo n*3, weight n*channels, pdf n); `w_in` = propagation direction.
    #[allow(clippy::too_many_arguments)]
    fn sample_local<'py>(
        &self,
        py: Python<'py>,
        points: F64In,
        w_in: F64In,
        lambda: F64In,
        channels: usize,
        u1: F64In,
        u2: F64In,
    ) -> PyResult<(F64Out<'py>, F64Out<'py>, F64Out<'py>)> {
        let (pts, dirs) = (triples(points.as_slice()?), triples(w_in.as_slice()?));
        let (lam, s1, s2) = (
            lambda.as_slice()?.to_vec(),
            u1.as_slice()?.to_vec(),
            u2.as_slice()?,
        );
        let n = pts.len();
        if dirs.len() != n
            || s1.len() != n
            || s2.len() != 2 * n
            || channels == 0
            || !per_lane(&lam, channels, n)
        {
            return Err(PyValueError::new_err(
                "points, w_in, u1, u2 and lambda must describe the same points",
            ));
        }
        let s2 = pairs(s2);
        let out = py.detach(|| {
            self.medium
                .sample_local(&pts, &dirs, &lam, channels, &s1, &s2)
        });
        Ok(sampled(py, out))
    }
}

/// Whether wavelengths `lam` are `channels` values shared by all `n` lanes or `channels` per lane.
fn per_lane(lam: &[f64], channels: usize, n: usize) -> bool {
    lam.len() == channels || lam.len() == channels * n
}

/// The second sample dimension (flat n*2) as pairs.
fn pairs(flat: &[f64]) -> Vec<[f64; 2]> {
    flat.chunks_exact(2).map(|c| [c[0], c[1]]).collect()
}

/// Sampled directions as numpy arrays: (wo n*3, weight n*channels, pdf n).
fn sampled(
    py: Python<'_>,
    (wo, w, pdf): (Vec<[f64; 3]>, Vec<f64>, Vec<f64>),
) -> (F64Out<'_>, F64Out<'_>, F64Out<'_>) {
    let wo: Vec<f64> = wo.into_iter().flatten().collect();
    (
        wo.into_pyarray(py),
        w.into_pyarray(py),
        pdf.into_pyarray(py),
    )
}

/// The lanes of an evaluation (`phase_eval`, `phase_mueller`) and their wavelengths.
fn eval_lanes(
    p: &F32In,
    wi: &F32In,
    wo: &F32In,
    lambda: &F64In,
    channels: usize,
) -> PyResult<(Vec<PhaseEvalLane>, Vec<f64>)> {
    let (pp, a, b, lam) = (
        vec3s(p, "p")?,
        vec3s(wi, "wi")?,
        vec3s(wo, "wo")?,
        lambda.as_slice()?.to_vec(),
    );
    if a.len() != pp.len() || b.len() != pp.len() || !per_lane(&lam, channels, pp.len()) {
        return Err(PyValueError::new_err(
            "p, wi, wo and lambda must describe the same lanes",
        ));
    }
    let lanes = pp
        .into_iter()
        .zip(a.into_iter().zip(b))
        .map(|(p, (wi, wo))| PhaseEvalLane { p, wi, wo })
        .collect();
    Ok((lanes, lam))
}
