"""Small scenes shared by the plugin tests, importable without ``conftest``'s side effects (a fresh cache
folder, hypothesis profiles): also inside the fresh interpreters that ``run_json`` starts.

* ``point_lit_cube`` — a scene dict: a medium in a cube under a point light and a constant sky.
* ``discrete_xml`` — a ``discrete`` medium element of a scene's XML.
* ``sensor_xml``, ``medium_xml`` — a perspective sensor and a medium (any type) as XML lines.
* ``run_json`` — run a snippet by ``python -c`` (with this folder importable) and read the JSON it printed last.
* ``phase_chi2`` — mitsuba.chi2's test of a phase function's sampling against its pdf.
"""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

HERE = pathlib.Path(__file__).resolve().parent


def point_lit_cube(mi, interior: dict, *, integrator: dict, fov: float, res: int, origin, target, light,
                   intensity: float, sky: float) -> dict:
    """A scene dict: the medium ``interior`` in a cube with a null BSDF, a point light at ``light`` (RGB
    intensity ``intensity``) and a constant sky (RGB radiance ``sky``), seen from ``origin`` towards ``target``
    by a ``res`` x ``res`` perspective camera of field of view ``fov`` with a box filter; ``integrator`` is
    the integrator's dict."""
    return {"type": "scene", "integrator": integrator,
            "sensor": {"type": "perspective", "fov": fov,
                       "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                       "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=[0, 1, 0])},
            "light": {"type": "point", "position": light, "intensity": {"type": "rgb", "value": intensity}},
            "env": {"type": "constant", "radiance": {"type": "rgb", "value": sky}},
            "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": interior}}


def discrete_xml(count, radius_median, more: str = "", ident: str = "") -> str:
    """The XML of a shape's interior ``discrete`` medium: ``count`` grains of median radius ``radius_median``
    um, 1 cm per scene unit, the properties ``more`` (XML) and the grains' own phase function; ``ident`` its
    id, if any. ``count`` may be a scene parameter (``"$count"``)."""
    id_attr = f' id="{ident}"' if ident else ""
    return (f'<medium type="discrete" name="interior"{id_attr}>'
            f'<integer name="count" value="{count}"/><float name="radius_median" value="{radius_median}"/>'
            f'<float name="scale_m" value="0.01"/>{more}<phase type="particle"/></medium>')


def run_json(code: str, *argv: str, env: dict | None = None, timeout: float = 600):
    """Run ``code`` in a fresh interpreter (``python -c``, arguments ``argv``, environment ``env``) that can
    import this module; it must succeed and print JSON on its last line, which is returned parsed."""
    code = f"import sys; sys.path.insert(0, {str(HERE)!r})\n" + code
    out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=timeout,
                         env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def sensor_xml(fov, origin: str, res="16", spp="$spp", sampler: str = "", film: str = "", indent: str = "  ") -> str:
    """A perspective sensor's XML lines: field of view ``fov`` from ``origin`` towards the origin (y up),
    ``spp`` samples a pixel (``sampler``: more of its properties), a ``res`` x ``res`` HDR film (``film``: more
    of its children)."""
    i, j = indent, indent * 2
    return (f'{i}<sensor type="perspective">\n{j}<float name="fov" value="{fov}"/>\n'
            f'{j}<transform name="to_world"><lookat origin="{origin}" target="0, 0, 0" up="0, 1, 0"/></transform>\n'
            f'{j}<sampler type="independent"><integer name="sample_count" value="{spp}"/>{sampler}</sampler>\n'
            f'{j}<film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/>'
            f'{film}</film>\n{i}</sensor>\n')


def medium_xml(kind: str, props, phase: str = "", attrs: str = 'name="interior"', indent: str = "    ",
               comment: str = "") -> str:
    """A medium element of type ``kind`` with ``attrs``: ``props`` as (tag, name, value) triples, then the phase
    child's XML ``phase`` (if any); ``comment`` a first line inside it."""
    inner = indent + "  "
    lines = [f'{indent}<medium type="{kind}" {attrs}>'] + ([f"{inner}<!-- {comment} -->"] if comment else [])
    lines += [f'{inner}<{tag} name="{name}" value="{value}"/>' for tag, name, value in props]
    lines += [inner + phase] if phase else []
    return "\n".join(lines + [f"{indent}</medium>"]) + "\n"


def phase_chi2(mi, dr, phase, mei_of, sample_count: int = 400_000):
    """mitsuba.chi2's ``ChiSquareTest`` (run) of ``phase``'s ``sample`` against its ``eval_pdf`` at the medium
    interactions ``mei_of(n)`` (``interactions_at_origin``): (passed, the test's messages)."""
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain

    ctx = mi.PhaseFunctionContext()

    def sample(s):
        wo, w, pdf = phase.sample(ctx, mei_of(dr.width(s)), s[0], mi.Vector2f(s[1], s[2]))
        return wo, dr.select(pdf > 0, mi.Float(1.0), mi.Float(0.0))

    def pdf(wo):
        return phase.eval_pdf(ctx, mei_of(dr.width(wo)), wo)[1]

    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         sample_count=sample_count, res=101, ires=8)
    return test.run(), test.messages


def interactions_at_origin(mi, dr, wi):
    """A function n -> n medium interactions at the origin with incident direction ``wi`` (phase-function
    tests: ``sample``/``eval_pdf`` of a `particle` phase attached to a site there)."""
    def mei_of(n):
        mei = dr.zeros(mi.MediumInteraction3f, n)
        mei.wi = wi
        mei.sh_frame = mi.Frame3f(mei.wi)
        mei.p = mi.Point3f(0, 0, 0)
        return mei
    return mei_of
