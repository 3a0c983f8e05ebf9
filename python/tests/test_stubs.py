"""The type stubs (raypick/__init__.pyi, with py.typed) say what the compiled module does: the
same public names, and for each function and method the same parameters in the same order
with the same defaults (a stub's ``...`` stands for a default it does not spell out)."""

import ast
import inspect
from pathlib import Path

import raypick

PACKAGE = Path(raypick.__file__).parent
STUB = PACKAGE / "__init__.pyi"


def _stub():
    tree = ast.parse(STUB.read_text())
    functions = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}
    (scene,) = [n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Scene"]
    members = {n.name: n for n in scene.body if isinstance(n, ast.FunctionDef)}
    (all_,) = [
        n.value
        for n in tree.body
        if isinstance(n, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in n.targets)
    ]
    return functions, members, ast.literal_eval(all_)


def _is_property(node):
    return any(getattr(d, "id", None) == "property" for d in node.decorator_list)


def _stub_parameters(node):
    args = node.args
    names = [a.arg for a in args.posonlyargs + args.args + args.kwonlyargs]
    positional = args.posonlyargs + args.args
    defaults = [inspect.Parameter.empty] * (len(positional) - len(args.defaults))
    defaults += [ast.literal_eval(d) for d in args.defaults]
    defaults += [inspect.Parameter.empty if d is None else ast.literal_eval(d) for d in args.kw_defaults]
    return list(zip(names, defaults))


def _runtime_parameters(function):
    return [(p.name, p.default) for p in inspect.signature(function).parameters.values()]


def test_the_stub_and_its_marker_are_installed():
    assert STUB.is_file(), STUB
    assert (PACKAGE / "py.typed").is_file(), PACKAGE


def test_the_stub_names_what_the_module_has():
    functions, members, all_ = _stub()
    assert all_ == raypick.__all__
    public_functions = {n for n in functions if not n.startswith("_")}
    assert public_functions == {n for n in raypick.__all__ if n not in ("Scene", "dask")}
    # The private ones the stub names (those raypick.dask imports) exist too.
    assert all(callable(getattr(raypick, n)) for n in functions)
    public = {n for n in dir(raypick.Scene) if not n.startswith("_")}
    assert set(members) == public, (set(members) ^ public)
    for name, node in members.items():
        runtime = inspect.getattr_static(raypick.Scene, name)
        assert _is_property(node) == inspect.isdatadescriptor(runtime), name


def test_the_stub_gives_each_function_its_parameters_and_defaults():
    functions, members, _ = _stub()
    pairs = [(getattr(raypick, n), node) for n, node in functions.items()]
    pairs += [
        (getattr(raypick.Scene, n), node) for n, node in members.items() if not _is_property(node)
    ]
    for function, node in pairs:
        stub = _stub_parameters(node)
        runtime = _runtime_parameters(function)
        assert [n for n, _ in stub] == [n for n, _ in runtime], (node.name, stub, runtime)
        for (name, said), (_, default) in zip(stub, runtime):
            if said is Ellipsis:
                # Only where the module cannot spell its default either (pyo3 writes `...`
                # for a value with no Python literal, such as tmax's infinity).
                assert default is Ellipsis, (node.name, name, default)
            else:
                assert said == default, (node.name, name, said, default)
