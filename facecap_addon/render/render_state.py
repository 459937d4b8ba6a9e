"""Whether this process has rendered. Once Blender has made an OpenGL context here, a child forked from this
process cannot render (its copy of the context hangs until the review's timeout), so the review page renders
in-process from then on (``review.render_guarded``). Every in-process render marks it first."""

#: ``rendered_here``: this process has rendered (or is about to).
STATE = {"rendered_here": False}


def mark_rendered():
    """Record that this process renders (call it before ``bpy.ops.render.render``)."""
    STATE["rendered_here"] = True


__all__ = ["STATE", "mark_rendered"]
