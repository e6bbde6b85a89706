//! The default wavelength sets (µm), one home for every table and renderer that needs one.

/// Representative wavelengths of the R, G, B channels: the monochromatic primaries of ITU-R BT.2020
/// (630, 532, 467 nm), which lie on the spectral locus. A documented choice, not an integration against
/// the channel responses.
pub const RGB_WAVELENGTHS_UM: [f64; 3] = [0.630, 0.532, 0.467];

/// The paper's 8 spectral samples over the visible range (Sec. 6): 380 to 780 nm, evenly spaced (the
/// values of numpy's `linspace(0.38, 0.78, 8)`, bit for bit).
pub fn spectral_wavelengths_um() -> [f64; 8] {
    let (start, stop) = (0.38, 0.78);
    let step = (stop - start) / 7.0;
    let mut out = [0.0; 8];
    for (i, v) in out.iter_mut().enumerate() {
        *v = i as f64 * step + start;
    }
    out[7] = stop;
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spectral_set_spans_the_visible() {
        let s = spectral_wavelengths_um();
        assert_eq!((s[0], s[7]), (0.38, 0.78));
        assert!(s
            .windows(2)
            .all(|w| (w[1] - w[0] - 0.4 / 7.0).abs() < 1e-15));
    }
}
