"""USD's own validators on a layer, in a fresh process (shared by the export tests).

``VALIDATE`` is a script: ``python -c VALIDATE FILE...`` registers the NeuralMaterialAPI plugin, runs every
registered ``pxr.UsdValidation`` validator on each stage and prints ``{file: [(validator, sites, message)]}``
of its errors as JSON. A fresh process, so the plugin registration and usd-core's Sdr discovery are clean."""

import textwrap

VALIDATE = textwrap.dedent("""
    import json, sys
    from mtlx2neural import usd_schema
    usd_schema.register()
    from pxr import Usd, UsdValidation as V
    ctx = V.ValidationContext(V.ValidationRegistry().GetOrLoadAllValidators())
    out = {}
    for name in sys.argv[1:]:
        errs = [e for e in ctx.Validate(Usd.Stage.Open(name)) if e.GetType() == V.ValidationErrorType.Error]
        out[name] = sorted({(e.GetName(), ",".join(str(s.GetPrim().GetPath()) if s.GetPrim() else ""
                                                   for s in e.GetSites()), e.GetMessage()) for e in errs})
    print(json.dumps(out))
""")
