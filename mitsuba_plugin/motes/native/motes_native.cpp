// motes_native: the native render path of the `discrete` medium and the `particle` phase function.
//
// Two Mitsuba 3.9 plugins in one library, built against the installed Mitsuba/Dr.Jit wheels by
// motes/native/__init__.py (the library is symlinked as plugins/motes_discrete_native.so and
// plugins/motes_particle_native.so; init_plugin registers the one it is loaded as):
//
// ======================  ========  =========================================================
// Parameter               Type      Meaning
// ======================  ========  =========================================================
// api                     integer   address of the Rust core's NativeApi (motes._motes.NATIVE_API)
// medium                  integer   a strong reference to the core medium (DiscreteMedium.native_handle())
// channel_nm_0..2         float     RGB and mono variants: the wavelength of each channel, nm
// polarizing              boolean   polarised variants: the grains' Mueller matrices (true), or a
//                                   depolarizer of their phase function (false: a user's phase, HG)
// description             string    what `to_string` reports (the Python plugin's summary)
// ======================  ========  =========================================================
//
// Scene parameters (`mi.traverse`): the medium lists `albedo_scale`, a one-element tensor, factor on every
// particle's albedo (1 as built); `parameters_changed` hands it to Rust, which checks it (an error names
// the parameter). In the scalar variants this medium is the scene's object itself (the Python `discrete`
// plugin's factory returns it, so no call goes through Python); in the LLVM ones the Python plugin stays
// the scene's object and forwards each traced call.
//
// Users never write these: the Python `discrete` plugin parses the scene's parameters, builds the
// particles and optics in Rust and creates these objects. All physics is in the Rust core
// (rust/motes-core/src/render/discrete/); this file only moves rays in and results out:
//
// * LLVM variants: each query is one `jit_llvm_ray_trace` call, the hook Mitsuba's own CPU ray tracers
//   use: inside Mitsuba's default *symbolic* kernels, drjit-core calls `packet<Width>` once per SIMD packet
//   with Embree's ray/hit record (structure of arrays), which goes unchanged to Rust (`motes_packet`,
//   rust/motes-py/src/native/mod.rs, documents which fields each operation reads and writes). Outputs come
//   back as the hit flag (geom_id != -1), t (= tfar), u, v, prim_id, geom_id and inst_id.
// * Scalar variants: the same Rust function is called directly with a one-lane record.
//
// Medium: `intersect_aabb` returns the next particle site as `mint` (Rust samples the free flight
// exactly), `get_majorant` a huge constant so that Mitsuba's tentative distance lands on the site, and
// `get_scattering_coefficients` sigma_s = sigma_t = that constant and sigma_n = 0, without a call: every
// tentative collision is a real scattering event, and the site's albedo is in the phase function's
// values and weights instead (Rust remembers the site as the path's event where the path's next call
// starts at it). Mitsuba's volumetric integrators multiply sigma_s / sigma_t and the phase function's
// value into a path alike, so the path carries the same product; `mei.sigma_s` itself reads as albedo 1.
// `is_homogeneous` (false as built) is set by `motes_native_set_clips_rays` (Python:
// motes.plugins.enclosure, for `volpath` and `volpathmis` only): those integrators then trace a ray that
// has a site only up to it, which is what their flag does there and nothing else, since this medium
// has no null collisions (Embree stops at the site: a dense cloud's rays no longer reach its walls).
// Phase function: `sample` (one call: the direction, its weights and pdf; spectral variants, whose four
// channels do not fit the record, evaluate the direction with a second call) and `eval_pdf`.
//
// Polarised variants (issue 45): `eval_pdf` returns the grains' Mueller matrix (Bohren & Huffman's F11,
// F12, F33, F34 of the site's mixture, from Rust, `PHASE_MUELLER`) rotated from the scattering plane's
// Stokes frames into Mitsuba's: light arrives along -wo and leaves along wi (swapped in importance
// transport, as Mitsuba's polarised BSDFs swap them), the frames' x axes are the in-plane directions
// cross(n, d) with n the scattering plane's normal (BH's "parallel" axes, so Q keeps BH's sign), and
// `mueller::rotate_mueller_basis` takes them to `mueller::stokes_basis` of each direction (Eradiate's
// `tabphase_polarized` does the same). `sample` draws the direction and pdf from F11 (unchanged) and
// evaluates the matrix there. Free flights are unpolarised.
#include <mitsuba/core/properties.h>
#include <mitsuba/render/medium.h>
#include <mitsuba/render/phase.h>
#include <mitsuba/render/mueller.h>
#include <mitsuba/core/distr_1d.h>
#include <cmath>
#include <sstream>
#include <vector>
#include <drjit/tensor.h>
#include <drjit-core/jit.h>
#include <algorithm>
#include <stdexcept>
#include <string>
#include <cstddef>
#include <cstring>

NAMESPACE_BEGIN(mitsuba)

/// The Rust core's C interface (rust/motes-py/src/native/mod.rs: NativeApi); abi must match.
struct MotesNativeApi {
    uint32_t abi;
    void (*packet)(const void *medium, uint32_t op, uint32_t width, const int32_t *valid, uint8_t *args,
                   const double *lambda, uint32_t channels);
    void (*release)(const void *medium);
    int32_t (*set_albedo_scale)(const void *medium, double scale, char *message, size_t capacity);
};
static constexpr uint32_t MOTES_NATIVE_ABI = 4;
enum MotesOp : uint32_t { FreeFlight = 0, PhaseSample = 2, PhaseEval = 3, PhaseMueller = 4, PhaseSampleDirection = 5 };
static constexpr uint32_t MOTES_OPS = 6;
/// sigma_t returned at a site; the tentative distance mint + E / MAJORANT rounds to the site itself.
static constexpr float MOTES_MAJORANT = 1e20f;
/// Per-lane wavelengths travel as u16 in units of 1/50 nm (native.rs).
static constexpr float MOTES_LAMBDA_UNITS_PER_NM = 50.f;

/// What a packet call needs: the API, the medium, the operation and the shared wavelengths (or null).
struct MotesPayload {
    const MotesNativeApi *api = nullptr;
    const void *medium = nullptr;
    uint32_t op = 0, channels = 1;
    const double *lambda = nullptr;
};

/// A sphere's Mueller matrix from Bohren & Huffman's elements `f` = (F11, F12, F33, F34) in the scattering
/// plane's Stokes frames, rotated into Mitsuba's (polarised variants; the file's notes): light arrives along
/// -wo and leaves along wi, swapped in importance transport.
template <typename Float, typename Spectrum, typename UnpolarizedSpectrum, typename Context, typename Vector3f>
Spectrum motes_sphere_mueller(const UnpolarizedSpectrum f[4], const Context &ctx, const Vector3f &wi,
                              const Vector3f &wo) {
    Spectrum m = dr::zeros<Spectrum>();
    m(0, 0) = f[0]; m(0, 1) = f[1]; m(1, 0) = f[1]; m(1, 1) = f[0];
    m(2, 2) = f[2]; m(2, 3) = f[3]; m(3, 2) = -f[3]; m(3, 3) = f[2];
    bool radiance = ctx.mode == TransportMode::Radiance;
    Vector3f wo_hat = radiance ? wo : wi, wi_hat = radiance ? wi : wo;
    Vector3f d_in = -wo_hat, d_out = wi_hat;
    Vector3f n = dr::cross(d_in, d_out);
    Float n2 = dr::squared_norm(n);
    // At θ = 0 and π the plane is undefined; a sphere's matrix is then the same in any (F12 = F34 = 0).
    n = dr::select(n2 > 1e-12f, n * dr::rsqrt(dr::maximum(n2, 1e-30f)), coordinate_system(d_in).first);
    Vector3f x_in = dr::normalize(dr::cross(n, d_in)), x_out = dr::normalize(dr::cross(n, d_out));
    return mueller::rotate_mueller_basis(m, d_in, x_in, mueller::stokes_basis(d_in), d_out, x_out,
                                         mueller::stokes_basis(d_out));
}

/// Called by the generated kernel once per packet of Width lanes.
template <size_t Width>
void motes_packet_fn(const int *valid, void *payload, void * /* ctx */, uint8_t *args) {
    const MotesPayload &p = *(const MotesPayload *) payload;
    p.api->packet(p.medium, p.op, (uint32_t) Width, Width > 1 ? (const int32_t *) valid : nullptr, args,
                  p.lambda, p.channels);
}

/// The state shared by both plugins: the core medium (a strong reference), its API, the channel
/// wavelengths of RGB variants, and one payload per operation.
template <typename Float, typename Spectrum> struct MotesCall {
    MI_IMPORT_TYPES()
    static constexpr size_t Channels = dr::size_v<UnpolarizedSpectrum>;

    const MotesNativeApi *api = nullptr;
    const void *medium = nullptr;
    double lambda[4] = { 0, 0, 0, 0 };
    MotesPayload payload[MOTES_OPS];
    void *func = nullptr;
    std::string description;

    /// Everything one native call returns.
    struct Out { Mask hit; Float t, u, v; UInt32 prim, geom, inst; };

    void init(const Properties &props, const char *who) {
        api = (const MotesNativeApi *) (uintptr_t) props.get<int64_t>("api");
        medium = (const void *) (uintptr_t) props.get<int64_t>("medium");
        if (!api || !medium)
            Throw("%s: needs the api and medium handles (created by the Python discrete plugin)", who);
        if (api->abi != MOTES_NATIVE_ABI)
            Throw("%s: the Rust core speaks native ABI %u, this plugin %u: rebuild it (motes.native.build())",
                  who, api->abi, MOTES_NATIVE_ABI);
        description = props.get<std::string>("description", std::string(who) + "[]");
        // RGB and mono variants: the channels' wavelengths, shared by every lane.
        bool shared = !is_spectral_v<Spectrum>;
        if (shared)
            for (size_t c = 0; c < Channels; ++c)
                lambda[c] = props.get<ScalarFloat>("channel_nm_" + std::to_string(c));
        for (uint32_t op = 0; op < MOTES_OPS; ++op)
            payload[op] = MotesPayload{ api, medium, op, (uint32_t) Channels, shared ? lambda : nullptr };
        if constexpr (dr::is_llvm_v<Float>) {
            switch (jit_llvm_vector_width()) {  // one instantiation per SIMD width the JIT may use
                case 1: func = (void *) motes_packet_fn<1>; break;
                case 4: func = (void *) motes_packet_fn<4>; break;
                case 8: func = (void *) motes_packet_fn<8>; break;
                case 16: func = (void *) motes_packet_fn<16>; break;
                default: Throw("%s: unsupported LLVM vector width %u", who, jit_llvm_vector_width());
            }
        }
    }

    MotesCall() = default;
    MotesCall(const MotesCall &) = delete;  // one release per handle
    MotesCall &operator=(const MotesCall &) = delete;
    /// Releases the core medium handle; also when the plugin's constructor throws after `init` read it.
    ~MotesCall() {
        if (api && medium)
            api->release(medium);
    }

    /// Per-lane wavelengths packed for Rust (spectral variants; zeros in RGB ones).
    static std::pair<UInt32, UInt32> packed_wavelengths(const Wavelength &wavelengths) {
        if constexpr (is_spectral_v<Spectrum>) {
            UInt32 w[4];
            for (size_t c = 0; c < 4; ++c)
                w[c] = c < Channels ? UInt32(dr::round(wavelengths[c] * MOTES_LAMBDA_UNITS_PER_NM)) & 0xFFFFu
                                    : UInt32(0);
            return { w[0] | (w[1] << 16), w[2] | (w[3] << 16) };
        } else {
            return { UInt32(0), UInt32(0) };
        }
    }

    /// The unit vector of an octahedral map (rust/motes-py/src/native/mod.rs): the lower hemisphere unfolded.
    static Vector3f octahedral(const Float &x, const Float &y) {
        Float z = 1.f - dr::abs(x) - dr::abs(y);
        Mask lower = z < 0.f;
        Float ux = dr::select(lower, dr::copysign(1.f - dr::abs(y), x), x),
              uy = dr::select(lower, dr::copysign(1.f - dr::abs(x), y), y);
        return dr::normalize(Vector3f(ux, uy, z));
    }

    /// One native call of operation `op` on the lanes `active`: the twelve inputs are the record's
    /// o, tnear, d, time, tfar (floats) and mask, id, flags (u32).
    Out call(uint32_t op, Mask active, const Vector3f &o, Float tnear, const Vector3f &d, Float time,
             Float tfar, UInt32 mask, UInt32 id, uint32_t flag = 0) const {
        if constexpr (dr::is_llvm_v<Float>) {
            UInt32 flags = UInt32(flag);
            Mask coherent = false;
            // Lanes outside the enclosing symbolic loop/call mask (finished paths, other media) are
            // skipped: combine `active` with Dr.Jit's mask stack, as Mitsuba's own ray tracers do.
            size_t size = dr::width(o, tnear, d, time, tfar, mask, id, active);
            active = Mask::steal(jit_var_mask_apply(active.index(), (uint32_t) size));
            // Every input as its own variable of the full width (literals broadcast by the JIT).
            uint32_t in[14] = { coherent.index(), active.index(), o.x().index(), o.y().index(), o.z().index(),
                                tnear.index(), d.x().index(), d.y().index(), d.z().index(), time.index(),
                                tfar.index(), mask.index(), id.index(), flags.index() };
            uint32_t out[8] = {};
            UInt64 func_v = UInt64::steal(jit_var_pointer(JitBackend::LLVM, func, 0, 0)),
                   payload_v = UInt64::steal(jit_var_pointer(JitBackend::LLVM, &payload[op], 0, 0));
            jit_llvm_ray_trace(func_v.index(), payload_v.index(), 0, in, out);
            Out r{ Mask::steal(out[0]), Float::steal(out[1]), Float::steal(out[2]), Float::steal(out[3]),
                   UInt32::steal(out[4]), UInt32::steal(out[5]), UInt32::steal(out[6]) };
            jit_var_dec_ref(out[7]);
            return r;
        } else if constexpr (!dr::is_jit_v<Float>) {
            // One lane: the record is 20 four-byte fields (Embree's RTCRayHit order).
            uint32_t rec[20];
            auto put = [&](int k, float x) { std::memcpy(&rec[k], &x, 4); };
            auto get = [&](int k) { float x; std::memcpy(&x, &rec[k], 4); return x; };
            put(0, o.x()); put(1, o.y()); put(2, o.z()); put(3, tnear);
            put(4, d.x()); put(5, d.y()); put(6, d.z()); put(7, time); put(8, tfar);
            rec[9] = mask; rec[10] = id; rec[11] = flag;
            for (int k = 12; k < 20; ++k) rec[k] = 0;
            rec[18] = (uint32_t) -1;  // geom_id: Rust writes 0 where it returns the lane
            if (active)
                api->packet(medium, op, 1, nullptr, (uint8_t *) rec, payload[op].lambda, (uint32_t) Channels);
            bool hit = active && rec[18] != (uint32_t) -1;
            return Out{ hit, hit ? get(8) : dr::Infinity<float>, get(15), get(16), rec[17], rec[18], rec[19] };
        } else {
            Throw("motes: the native render path has no CUDA backend");
        }
    }

    /// Up to four channel values from t, u, v, prim_id (as float bits).
    static UnpolarizedSpectrum channels_of(const Out &r) {
        UnpolarizedSpectrum s(0.f);
        Float v[4] = { r.t, r.u, r.v, dr::reinterpret_array<Float>(r.prim) };
        for (size_t c = 0; c < Channels && c < 4; ++c)
            s[c] = dr::select(r.hit, v[c], 0.f);
        return s;
    }
};

template <typename Float, typename Spectrum>
class MotesDiscreteNative final : public Medium<Float, Spectrum> {
public:
    MI_IMPORT_BASE(Medium, m_is_homogeneous, m_has_spectral_extinction)
    MI_IMPORT_TYPES()

    MotesDiscreteNative(const Properties &props) : Base(props) {
        m_is_homogeneous = false;
        m_has_spectral_extinction = false;  // grey free flights (render/discrete, "Colour")
        m_call.init(props, "motes_discrete_native");
        m_albedo_scale = TensorXf(dr::full<typename TensorXf::Array>(1.f, 1));
    }

    std::tuple<Mask, Float, Float> intersect_aabb(const Ray3f &ray) const override {
        Float zero = dr::zeros<Float>();
        auto [w0, w1] = Call::packed_wavelengths(ray.wavelengths);
        auto r = m_call.call(FreeFlight, Mask(true), ray.o, zero, ray.d, zero, Float(ray.maxt), w0, w1);
        return { r.hit, dr::select(r.hit, r.t, dr::Infinity<Float>),
                 dr::select(r.hit, dr::Infinity<Float>, -dr::Infinity<Float>) };
    }

    UnpolarizedSpectrum get_majorant(const MediumInteraction3f &, Mask active) const override {
        // MAJORANT where intersect_aabb found a site, 0 elsewhere (see the file's notes).
        return dr::select(active, UnpolarizedSpectrum(MOTES_MAJORANT), UnpolarizedSpectrum(0.f));
    }

    std::tuple<UnpolarizedSpectrum, UnpolarizedSpectrum, UnpolarizedSpectrum>
    get_scattering_coefficients(const MediumInteraction3f &, Mask active) const override {
        // Every site scatters; its albedo is in the phase function (see the file's notes).
        UnpolarizedSpectrum sigma_t = dr::select(active, UnpolarizedSpectrum(MOTES_MAJORANT), UnpolarizedSpectrum(0.f));
        return { sigma_t, UnpolarizedSpectrum(0.f), sigma_t };
    }

    void traverse(TraversalCallback *cb) override {
        Base::traverse(cb);
        cb->put("albedo_scale", m_albedo_scale, ParamFlags::NonDifferentiable);
    }

    void parameters_changed(const std::vector<std::string> &keys) override {
        if (!keys.empty() && std::find(keys.begin(), keys.end(), "albedo_scale") == keys.end())
            return;
        // std::invalid_argument reaches Python as ValueError (the LLVM variants' Python plugin raises
        // MotesError, a ValueError, for the same value).
        if (dr::width(m_albedo_scale.array()) != 1)
            throw std::invalid_argument("discrete medium: albedo_scale must hold one value, got " +
                                        std::to_string(dr::width(m_albedo_scale.array())));
        double scale = (double) dr::slice(m_albedo_scale.array(), 0);
        char message[512] = { 0 };
        if (m_call.api->set_albedo_scale(m_call.medium, scale, message, sizeof(message)) != 0) {
            // The parameter goes back to the value in use, so that what mi.traverse shows is true.
            m_albedo_scale = TensorXf(dr::full<typename TensorXf::Array>((float) m_applied_scale, 1));
            throw std::invalid_argument(std::string("discrete medium: ") + message);
        }
        m_applied_scale = scale;
    }

    std::string to_string() const override { return m_call.description; }
    /// The core medium handle (motes_native_medium_handle).
    const void *handle() const { return m_call.medium; }
    /// Let integrators clip a ray at its site (motes_native_set_clips_rays).
    void set_clips_rays(bool on) { m_is_homogeneous = on; }
    /// What `to_string` reports (motes_native_set_description: a filled medium's particles).
    void set_description(const char *text) { m_call.description = text; }
    MI_DECLARE_CLASS(MotesDiscreteNative)

private:
    using Call = MotesCall<Float, Spectrum>;
    Call m_call;
    TensorXf m_albedo_scale;
    double m_applied_scale = 1.0;
    MI_TRAVERSE_CB(Base, m_albedo_scale)
};

template <typename Float, typename Spectrum>
class MotesParticleNative final : public PhaseFunction<Float, Spectrum> {
public:
    MI_IMPORT_BASE(PhaseFunction, m_flags, m_components)
    MI_IMPORT_TYPES(PhaseFunctionContext)

    MotesParticleNative(const Properties &props) : Base(props) {
        m_flags = +PhaseFunctionFlags::Anisotropic;
        m_components.push_back(m_flags);
        m_call.init(props, "motes_particle_native");
        m_polarizing = props.get<bool>("polarizing", false);
    }

    std::tuple<Vector3f, Spectrum, Float> sample(const PhaseFunctionContext &ctx, const MediumInteraction3f &mi,
                                                 Float sample1, const Point2f &sample2,
                                                 Mask active) const override {
        auto [w0, w1] = Call::packed_wavelengths(mi.wavelengths);
        constexpr bool polarized = is_polarized_v<Spectrum>;
        auto r = m_call.call(polarized ? PhaseSampleDirection : PhaseSample, active, mi.p, sample1, mi.wi,
                             sample2.x(), sample2.y(), w0, w1);
        if constexpr (Call::Channels <= 3 && !polarized) {
            // Direction (octahedral), weights and pdf in one call.
            Float pdf = dr::select(r.hit, dr::reinterpret_array<Float>(r.inst), 0.f);
            Mask ok = active && r.hit && pdf > 0.f;
            UnpolarizedSpectrum weight(0.f);
            Float w[3] = { r.v, dr::reinterpret_array<Float>(r.prim), dr::reinterpret_array<Float>(r.geom) };
            for (size_t c = 0; c < Call::Channels; ++c)
                weight[c] = dr::select(ok, w[c], 0.f);
            return { dr::select(ok, Call::octahedral(r.t, r.u), Vector3f(0.f, 0.f, 1.f)), Spectrum(weight),
                     dr::select(ok, pdf, 0.f) };
        } else {
            Vector3f wo(r.t, r.u, r.v);
            Float pdf = dr::select(r.hit, dr::reinterpret_array<Float>(r.prim), 0.f);
            Mask ok = active && r.hit && pdf > 0.f;
            auto [value, pdf_eval] = eval_pdf(ctx, mi, wo, ok);
            Spectrum weight = dr::select(ok, value / dr::select(ok, pdf, 1.f), dr::zeros<Spectrum>());
            return { dr::select(ok, wo, Vector3f(0.f, 0.f, 1.f)), weight, dr::select(ok, pdf, 0.f) };
        }
    }

    std::pair<Spectrum, Float> eval_pdf(const PhaseFunctionContext &ctx, const MediumInteraction3f &mi,
                                        const Vector3f &wo, Mask active) const override {
        auto [w0, w1] = Call::packed_wavelengths(mi.wavelengths);
        if constexpr (is_polarized_v<Spectrum>) {
            if (m_polarizing)
                return eval_mueller(ctx, mi, wo, active, w0, w1);
        }
        auto r = m_call.call(PhaseEval, active, mi.p, wo.x(), mi.wi, wo.y(), wo.z(), w0, w1);
        Float pdf = dr::select(r.hit, dr::reinterpret_array<Float>(r.inst), 0.f);
        // Polarised variants without the grains' matrices: a depolarizer, as Mitsuba's own phase functions.
        return { depolarizer<Spectrum>(Spectrum(Call::channels_of(r))), pdf };
    }

    std::string to_string() const override { return m_call.description; }
    MI_DECLARE_CLASS(MotesParticleNative)

private:
    using Call = MotesCall<Float, Spectrum>;

    /// The grains' Mueller matrix towards `wo` in Mitsuba's Stokes frames, and the pdf (file notes).
    std::pair<Spectrum, Float> eval_mueller(const PhaseFunctionContext &ctx, const MediumInteraction3f &mi,
                                            const Vector3f &wo, Mask active, const UInt32 &w0,
                                            const UInt32 &w1) const {
        UnpolarizedSpectrum f[4];
        Float pdf;
        if constexpr (Call::Channels == 1) {
            // One channel: F11, F12, F33, F34 in one call.
            auto r = m_call.call(PhaseMueller, active, mi.p, wo.x(), mi.wi, wo.y(), wo.z(), w0, w1, 0);
            Float v[4] = { r.t, r.u, r.v, dr::reinterpret_array<Float>(r.prim) };
            for (int e = 0; e < 4; ++e)
                f[e] = UnpolarizedSpectrum(dr::select(r.hit, v[e], 0.f));
            pdf = dr::select(r.hit, dr::reinterpret_array<Float>(r.inst), 0.f);
        } else {
            // Element e of every channel per call; the first evaluates, the others read it again.
            for (uint32_t e = 0; e < 4; ++e) {
                auto r = m_call.call(PhaseMueller, active, mi.p, wo.x(), mi.wi, wo.y(), wo.z(), w0, w1, e);
                f[e] = Call::channels_of(r);
                if (e == 0)
                    pdf = dr::select(r.hit, dr::reinterpret_array<Float>(r.inst), 0.f);
            }
        }
        Spectrum m = motes_sphere_mueller<Float, Spectrum>(f, ctx, mi.wi, wo);
        return { dr::select(active, m, dr::zeros<Spectrum>()), pdf };
    }

    Call m_call;
    bool m_polarizing = false;
    MI_TRAVERSE_CB(Base)
};

/// `motes_tabphase_polarized`: a tabulated phase function with a sphere ensemble's polarisation, for the
/// continuous equivalent of a `discrete` medium in polarised variants (motes.homogeneous_equivalent with
/// polarized=True). Mainline Mitsuba's `tabphase` depolarises.
///
/// ======  ======  ==============================================================================
/// values  string  F11 on a regular grid of cos(theta) from -1 (backward) to 1 (forward), as `tabphase`
/// m12     string  F12 / F11 on the same grid (Bohren & Huffman's elements; 0 where omitted)
/// m33     string  F33 / F11 (1 where omitted)
/// m34     string  F34 / F11 (0 where omitted)
/// ======  ======  ==============================================================================
///
/// Sampling and pdf are `tabphase`'s (F11, normalised); in polarised variants `eval_pdf` returns the matrix
/// of `motes_sphere_mueller` with the ratios interpolated linearly, `sample` that matrix over the pdf.
template <typename Float, typename Spectrum>
class MotesTabphasePolarized final : public PhaseFunction<Float, Spectrum> {
public:
    MI_IMPORT_BASE(PhaseFunction, m_flags, m_components)
    MI_IMPORT_TYPES(PhaseFunctionContext)
    using FloatStorage = DynamicBuffer<Float>;

    MotesTabphasePolarized(const Properties &props) : Base(props) {
        std::vector<ScalarFloat> f = parse(props, "values", {});
        if (f.size() < 2)
            Throw("motes_tabphase_polarized: 'values' needs at least two numbers, got %zu", f.size());
        for (ScalarFloat v : f)
            if (!(v >= 0.f) || !std::isfinite(v))
                Throw("motes_tabphase_polarized: 'values' must be finite and >= 0, got %f", v);
        m_distr = ContinuousDistribution<Float>(ScalarVector2f(-1.f, 1.f), f.data(), f.size());
        const char *names[3] = { "m12", "m33", "m34" };
        ScalarFloat fill[3] = { 0.f, 1.f, 0.f };
        for (int k = 0; k < 3; ++k) {
            std::vector<ScalarFloat> r = parse(props, names[k], std::vector<ScalarFloat>(f.size(), fill[k]));
            if (r.size() != f.size())
                Throw("motes_tabphase_polarized: '%s' has %zu values, 'values' %zu", names[k], r.size(), f.size());
            for (ScalarFloat v : r)
                if (!(std::abs(v) <= 1.f + 1e-5f))
                    Throw("motes_tabphase_polarized: '%s' holds %f: ratios to F11 lie in [-1, 1]", names[k], v);
            m_ratio[k] = dr::load<FloatStorage>(r.data(), r.size());
        }
        m_size = (uint32_t) f.size();
        m_flags = +PhaseFunctionFlags::Anisotropic;
        m_components.push_back(m_flags);
    }

    std::tuple<Vector3f, Spectrum, Float> sample(const PhaseFunctionContext &ctx, const MediumInteraction3f &mi,
                                                 Float /* sample1 */, const Point2f &sample2,
                                                 Mask active) const override {
        // cos θ = dot(wo, -wi): θ between the light's directions before and after (file notes).
        auto [cos_theta, pdf_mu] = m_distr.sample_pdf(sample2.x(), active);
        Float sin_theta = dr::safe_sqrt(1.f - cos_theta * cos_theta);
        auto [s, c] = dr::sincos(dr::TwoPi<Float> * sample2.y());
        Vector3f wo = Frame3f(-mi.wi).to_world(Vector3f(sin_theta * c, sin_theta * s, cos_theta));
        auto [value, pdf] = eval_pdf(ctx, mi, wo, active);
        Spectrum weight = dr::select(pdf > 0.f, value / dr::select(pdf > 0.f, pdf, 1.f), dr::zeros<Spectrum>());
        return { wo, weight, pdf };
    }

    std::pair<Spectrum, Float> eval_pdf(const PhaseFunctionContext &ctx, const MediumInteraction3f &mi,
                                        const Vector3f &wo, Mask active) const override {
        Float cos_theta = dr::clip(-dr::dot(wo, mi.wi), -1.f, 1.f);
        Float pdf = dr::select(active, m_distr.eval_pdf_normalized(cos_theta, active) * dr::InvTwoPi<Float>, 0.f);
        if constexpr (is_polarized_v<Spectrum>) {
            Float x = (cos_theta + 1.f) * .5f * (m_size - 1);
            UInt32 i = dr::clip(UInt32(x), 0u, m_size - 2);
            Float t = x - Float(i);
            UnpolarizedSpectrum f[4];
            f[0] = UnpolarizedSpectrum(pdf);
            for (int k = 0; k < 3; ++k) {
                Float a = dr::gather<Float>(m_ratio[k], i, active), b = dr::gather<Float>(m_ratio[k], i + 1u, active);
                f[k + 1] = UnpolarizedSpectrum(pdf * dr::lerp(a, b, t));
            }
            return { motes_sphere_mueller<Float, Spectrum>(f, ctx, mi.wi, wo), pdf };
        } else {
            return { Spectrum(pdf), pdf };
        }
    }

    std::string to_string() const override { return "MotesTabphasePolarized[" + std::to_string(m_size) + " values]"; }
    MI_DECLARE_CLASS(MotesTabphasePolarized)

private:
    /// A string property of comma- or space-separated numbers (`fallback` when it is absent).
    static std::vector<ScalarFloat> parse(const Properties &props, const std::string &name,
                                          std::vector<ScalarFloat> fallback) {
        if (!props.has_property(name))
            return fallback;
        std::vector<ScalarFloat> out;
        std::string text = props.get<std::string>(name);
        for (char &ch : text)
            if (ch == ',')
                ch = ' ';
        std::istringstream in(text);
        std::string word;
        while (in >> word) {
            try {
                out.push_back((ScalarFloat) std::stod(word));
            } catch (const std::exception &) {
                Throw("motes_tabphase_polarized: '%s' holds \"%s\", not a number", name, word);
            }
        }
        return out;
    }

    ContinuousDistribution<Float> m_distr;
    FloatStorage m_ratio[3];
    uint32_t m_size = 0;
    MI_TRAVERSE_CB(Base)
};

NAMESPACE_END(mitsuba)

using namespace mitsuba;

template <template <typename, typename> class Cls, typename Float, typename Spectrum>
static ref<Object> motes_make(void *, const Properties &p) { return new Cls<Float, Spectrum>(p); }

template <template <typename, typename> class Cls>
static void motes_register(std::string_view name, PluginRegisterFn fn) {
    using LF = dr::DiffArray<JitBackend::LLVM, float>;
    fn(name, "scalar_rgb", Cls<float, Color<float, 3>>::Type, motes_make<Cls, float, Color<float, 3>>);
    fn(name, "scalar_spectral", Cls<float, Spectrum<float, 4>>::Type, motes_make<Cls, float, Spectrum<float, 4>>);
    fn(name, "llvm_ad_rgb", Cls<LF, Color<LF, 3>>::Type, motes_make<Cls, LF, Color<LF, 3>>);
    fn(name, "llvm_ad_spectral", Cls<LF, Spectrum<LF, 4>>::Type, motes_make<Cls, LF, Spectrum<LF, 4>>);
    using SP = MuellerMatrix<Spectrum<float, 4>>;
    using LSP = MuellerMatrix<Spectrum<LF, 4>>;
    using LMP = MuellerMatrix<Color<LF, 1>>;
    fn(name, "scalar_spectral_polarized", Cls<float, SP>::Type, motes_make<Cls, float, SP>);
    fn(name, "llvm_ad_spectral_polarized", Cls<LF, LSP>::Type, motes_make<Cls, LF, LSP>);
    fn(name, "llvm_ad_mono_polarized", Cls<LF, LMP>::Type, motes_make<Cls, LF, LMP>);
}

/// `f` of the first variant's medium that `obj` is, or `none` (the variants registered above).
template <typename Obj, typename F, typename R>
static R motes_for_medium(Obj *obj, F f, R none) {
    using LF = dr::DiffArray<JitBackend::LLVM, float>;
    if (auto m = dynamic_cast<MotesDiscreteNative<float, Color<float, 3>> *>(obj)) return f(m);
    if (auto m = dynamic_cast<MotesDiscreteNative<float, Spectrum<float, 4>> *>(obj)) return f(m);
    if (auto m = dynamic_cast<MotesDiscreteNative<LF, Color<LF, 3>> *>(obj)) return f(m);
    if (auto m = dynamic_cast<MotesDiscreteNative<LF, Spectrum<LF, 4>> *>(obj)) return f(m);
    if (auto m = dynamic_cast<MotesDiscreteNative<float, MuellerMatrix<Spectrum<float, 4>>> *>(obj)) return f(m);
    if (auto m = dynamic_cast<MotesDiscreteNative<LF, MuellerMatrix<Spectrum<LF, 4>>> *>(obj)) return f(m);
    if (auto m = dynamic_cast<MotesDiscreteNative<LF, MuellerMatrix<Color<LF, 1>>> *>(obj)) return f(m);
    return none;
}

// Registers the variants built here (MI_EXPORT_PLUGIN would instantiate all 13), for the plugin name this
// library was loaded as.
extern "C" MI_EXPORT void init_plugin(std::string_view name, PluginRegisterFn fn) {
    if (name == "motes_particle_native")
        motes_register<MotesParticleNative>(name, fn);
    else if (name == "motes_tabphase_polarized")
        motes_register<MotesTabphasePolarized>(name, fn);
    else
        motes_register<MotesDiscreteNative>(name, fn);
}

/// The core medium handle of a `motes_discrete_native` object (its address, as Python's `.ptr`), or null for
/// any other object: how Python finds the data of a scene whose medium is this plugin (scalar variants).
extern "C" MI_EXPORT const void *motes_native_medium_handle(const Object *obj) {
    return motes_for_medium(const_cast<Object *>(obj), [](auto *m) { return m->handle(); }, (const void *) nullptr);
}

/// Set whether a `motes_discrete_native` object lets integrators clip a ray at its site (Mitsuba's
/// `is_homogeneous` flag; see the file's notes): 1 if `obj` is one, else 0 (nothing changed).
extern "C" MI_EXPORT int motes_native_set_clips_rays(Object *obj, int on) {
    return motes_for_medium(obj, [on](auto *m) { return m->set_clips_rays(on != 0), 1; }, 0);
}

/// Set what a `motes_discrete_native` object's `to_string` reports: 1 if `obj` is one, else 0.
extern "C" MI_EXPORT int motes_native_set_description(Object *obj, const char *text) {
    return motes_for_medium(obj, [text](auto *m) { return m->set_description(text), 1; }, 0);
}

/// The Mitsuba version this library was compiled against (checked by motes/native/__init__.py).
extern "C" MI_EXPORT const char *motes_native_mitsuba_version() { return MI_VERSION; }
