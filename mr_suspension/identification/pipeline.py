"""One damper's diagnosis, from its record files to a report folder.

:func:`diagnose_to_dir` is the work of ``mr-suspension diagnose`` once its options are parsed;
``diagnose-fleet`` (:mod:`~mr_suspension.identification.fleet`) runs it once per record set.
"""

import time
import warnings

from mr_suspension.identification import data as dataio
from mr_suspension.identification import diagnose, report


def diagnose_to_dir(paths, out_dir, opts, effects, n_folds, nominal, validate=(),
                    make_plots=True, progress=None, on_load=None):
    """Load ``paths`` (one damper's records), diagnose, write the report into ``out_dir``.

    What ``diagnose`` does after parsing its options (``diagnose-fleet`` runs it once per
    record set). ``on_load(warnings)`` is called with the input warnings once the records are
    loaded. Returns ``(report dict, DiagnosisResult, input warnings)``.
    """
    t0 = time.time()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        records = dataio.load_records(paths, opts)
        validate = dataio.load_records(validate, opts) if validate else []
    notes = [str(w.message) for w in caught]
    if on_load is not None:
        on_load(notes)
    res = diagnose.Diagnosis(effects=effects, n_folds=n_folds, nominal_driver=nominal,
                             progress=progress).fit(records)
    rep, _ = report.write(res, records, out_dir, validate, time.time() - t0,
                          make_plots=make_plots, input_warnings=notes)
    return rep, res, notes
