"""The type stubs describe the extension module as it is."""

import ast
import pathlib

import ndr
from ndr import _native

STUB = pathlib.Path(ndr.__file__).with_name("_native.pyi")


def stub_names():
    tree = ast.parse(STUB.read_text(encoding="utf-8"))
    names = set()
    for node in tree.body:
        if isinstance(node, (ast.ClassDef, ast.FunctionDef)):
            names.add(node.name)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
    private = ("_Link", "_Listener", "_LinkSettings", "_regulation")
    return {n for n in names if not n.startswith("_") or n in private}


def test_every_native_name_has_a_stub_and_every_stub_exists():
    native = {n for n in dir(_native) if not n.startswith("__")}
    stubs = stub_names()
    assert native - stubs == set(), "names without a stub"
    assert stubs - native == set(), "stubs of names that do not exist"


def test_the_package_exports_what_it_lists():
    for name in ndr.__all__:
        assert hasattr(ndr, name), name
