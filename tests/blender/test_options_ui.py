"""Every take-config option has a sidebar control or says why it is headless-only, every sidebar
setting is an option or says why not, and the controls built from the option table agree with it."""

import bpy
import pytest

from facecap.facecap_addon.ui import properties, properties_video
from facecap.solvers.options import OPTIONS

GROUPS = {"facecap": properties.FACECAP_PG_settings, "facecap.video": properties_video.FACECAP_PG_video}


def _settings_props(group):
    return {p.identifier: p for p in GROUPS[group].bl_rna.properties if p.identifier not in ("rna_type", "name")}


def _controls(option):
    return [c.strip() for c in option.ui.split(",") if c.strip()]


def _resolve(control):
    """(kind, RNA property) of a control named in an option's ``ui``."""
    if control.startswith("op:"):
        idname, prop = control[3:].rsplit(".", 1)
        module, name = idname.split(".")
        rna = getattr(getattr(bpy.ops, module), name).get_rna_type()
        return "operator", rna.properties.get(prop)
    group, prop = control.rsplit(".", 1)
    return "setting", _settings_props(group).get(prop)


@pytest.mark.parametrize("option", OPTIONS, ids=lambda o: o.name)
def test_every_option_has_a_control_or_a_reason(option):
    if not option.ui:
        assert option.headless, f"[{option.name}] has no sidebar control and no headless reason"
        return
    for control in _controls(option):
        kind, prop = _resolve(control)
        assert prop is not None, f"[{option.name}] names {control}, which does not exist"


def test_every_sidebar_setting_is_an_option_or_sidebar_only():
    named = {c for o in OPTIONS for c in _controls(o) if not c.startswith("op:")}
    missing = []
    for group in GROUPS:
        for prop in _settings_props(group):
            full = f"{group}.{prop}"
            short = full.removeprefix("facecap.")
            if full not in named and short not in properties.SIDEBAR_ONLY:
                missing.append(full)
    stale = [k for k in properties.SIDEBAR_ONLY if f"facecap.{k}" in named]
    assert not missing, f"sidebar settings that are neither an option's control nor in SIDEBAR_ONLY: {missing}"
    assert not stale, f"SIDEBAR_ONLY lists settings that are options' controls: {stale}"


@pytest.mark.parametrize("option", [o for o in OPTIONS if o.ui], ids=lambda o: o.name)
def test_controls_agree_with_the_option(option):
    for control in _controls(option):
        kind, prop = _resolve(control)
        if prop.type == "ENUM" and option.choices:
            items = {item.identifier for item in prop.enum_items}
            # AUTO: the file decides; NONE: the option left out (the Solve panel's target without [rig])
            if items <= {"AUTO", "NONE"} | set(option.choices) | {c.upper() for c in option.choices}:
                continue
            assert items <= set(option.choices), f"{control}: items {sorted(items)} not in {option.choices}"
        if kind == "setting" and prop.type in ("FLOAT", "INT") and not getattr(prop, "is_array", False) \
                and option.kind in ("float", "int") and option.default is not None:
            assert prop.default == pytest.approx(option.default), f"{control} default differs from [{option.name}]"
            if option.low is not None:
                assert prop.hard_min >= option.low - 1e-12, f"{control} allows values below [{option.name}]"
            if option.high is not None:
                assert prop.hard_max <= option.high + 1e-12, f"{control} allows values above [{option.name}]"
