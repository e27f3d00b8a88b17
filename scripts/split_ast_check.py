"""Branch splits' proof of no behaviour change, by the code: every top-level definition of the old
verdict.py / calibrate.py / doctor.py is in the new modules with an equal AST after the renames
(docstrings, annotations and function-level imports aside; module-qualified calls such as C.gls
read as gls). docs/measurements/splits.md.

    mkdir -p /tmp/old && git archive d7e0779 tvsd | tar -x -C /tmp/old
    .venv/bin/python scripts/split_ast_check.py /tmp/old/tvsd/analysis tvsd/analysis
"""
import ast, re, sys
from pathlib import Path
OLD, NEW = Path(sys.argv[1]), Path(sys.argv[2])
RENAME = {
 '_ar_filter':'ar_filter','_whiten':'whiten','_orth':'orth','_floor':'block_floor','_excitation_rows':'excitation_rows',
 '_line_scan':'line_scan','_refine_frequency':'refine_frequency','_refit_input':'refit_input','_dissolved':'dissolved',
 '_convention_unpinned':'convention_unpinned','_structural_lr':'structural_lr','_drift_agrees':'window_refits_agree',
 '_drift_trend':'confirmed','_trend_agrees':'trend_agrees','_physical':'physical','_reduced':'reduced',
 '_instrumented_check':'instrumented_check','_peak_in_plant':'peak_in_plant','_closed_loop_note':'closed_loop_note',
}
# Removed on purpose: read nowhere (the held-out split is heldout_sim.D_SPLIT).
REMOVED = {'HOLDOUT_SPLIT'}


def norm(node):
    src = ast.unparse(node)
    # module-qualified calls → bare names (C.gls → gls, refit.x → x, drift.agrees → agrees, ...)
    src = re.sub(r'\b(C|refit|drift|crossval|heldout_sim|calibrate)\.(?=[A-Za-z_])', '', src)
    for a, b in RENAME.items():
        src = re.sub(r'\b' + a + r'\b', b, src)
    t = ast.parse(src)
    for n in ast.walk(t):  # docstrings and annotations may differ (comments pointing at new homes)
        if isinstance(n, (ast.FunctionDef, ast.ClassDef)) and n.body and isinstance(n.body[0], ast.Expr) and isinstance(getattr(n.body[0], 'value', None), ast.Constant):
            n.body = n.body[1:]
        if isinstance(n, ast.FunctionDef):
            n.returns = None
            for a in n.args.args: a.annotation = None
        if isinstance(n, ast.AnnAssign) and n.simple:
            n.annotation = ast.Name('_')
    # drop function-level imports (moved to module level)
    for n in ast.walk(t):
        if hasattr(n, 'body') and isinstance(n.body, list):
            n.body = [b for b in n.body if not isinstance(b, (ast.Import, ast.ImportFrom))]
    return ast.dump(t)
def defs(path):
    out = {}
    for n in ast.parse(path.read_text()).body:
        if isinstance(n, (ast.FunctionDef, ast.ClassDef)): out[n.name] = n
        elif isinstance(n, (ast.Assign, ast.AnnAssign)):
            tg = n.targets[0] if isinstance(n, ast.Assign) else n.target
            if isinstance(tg, ast.Name): out[tg.id] = n
    return out
new = {}
for p in NEW.glob('*.py'):
    for k, v in defs(p).items(): new.setdefault(RENAME.get(k, k), []).append((p.name, v))
bad = 0
for mod in ('verdict.py', 'calibrate.py', 'doctor.py'):
    for name, node in defs(OLD / mod).items():
        if name == '__all__' or name in REMOVED: continue
        nn = RENAME.get(name, name)
        cands = new.get(nn, [])
        ok = [f for f, v in cands if norm(v) == norm(node)]
        print(f'{mod}:{name} -> {nn}: ' + (f'same in {ok}' if ok else f'DIFFERENT/MISSING (candidates {[f for f,_ in cands]})'))
        bad += not ok
print('bad', bad); sys.exit(bad > 0)
