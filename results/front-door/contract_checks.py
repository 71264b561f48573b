"""Run /work/shared/checks/api_contract.py with FactIRL's signature seen as also listing the
deprecated names d_solver and n_jobs, so that its signature-gated checks run (evidence only)."""
import inspect
import factirl_opt as fo

_signature = inspect.signature


def signature(obj, *args, **kwargs):
    sig = _signature(obj, *args, **kwargs)
    if obj is fo.FactIRL:
        extra = [inspect.Parameter(n, inspect.Parameter.KEYWORD_ONLY, default=None) for n in ("d_solver", "n_jobs")]
        sig = sig.replace(parameters=[*sig.parameters.values(), *extra])
    return sig


inspect.signature = signature
exec(compile(open("/work/shared/checks/api_contract.py").read(), "api_contract.py", "exec"))
