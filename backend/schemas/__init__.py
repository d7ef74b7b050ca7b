"""Request/response models of the resource routers: ``XCreate`` (input, every field bounded),
``XPublic`` (output) and ``XsPublic`` list wrappers ``{data, count}`` (STYLE.md)."""
