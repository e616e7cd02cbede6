"""Propagation methods: the registry, the contract and the built-in methods."""

from uqflow.errors import StudyError
from uqflow.layout import METHOD, STATISTICS_GROUP
from uqflow.methods.base import (MethodOptions, PropagationMethod, finish_statistics,
                                 get_method, make_design, method_registry, ok_mask,
                                 output_names, register_method, sample_mask)


def compare_results(trees: list, folder, figures: bool = True) -> tuple[str, list]:
    """What the methods of ``trees`` say of them side by side (``PropagationMethod.compare``),
    each comparison once (multilevel and multifidelity share theirs); ``uqflow report``
    prints it after the results' own reports."""
    texts, paths, asked = [], [], set()
    for tree in trees:
        source = tree[STATISTICS_GROUP].attrs if STATISTICS_GROUP in tree.children \
            else tree.attrs
        try:
            compare = get_method(str(source.get(METHOD, ""))).compare
        except StudyError:  # a method not installed here
            continue
        if compare.__func__ in asked:
            continue
        asked.add(compare.__func__)
        text, written = compare(trees, folder, figures=figures)
        texts += [text] if text else []
        paths += written
    return "\n".join(texts), paths


__all__ = ["PropagationMethod", "MethodOptions", "register_method", "get_method",
           "method_registry", "make_design", "finish_statistics", "ok_mask", "output_names",
           "sample_mask", "compare_results"]
