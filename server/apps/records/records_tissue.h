#pragma once
// telehand-records fit / synth for the massage: a capture of the web between thumb and index
// fitted into a patient case's [tissue] section with a plot per tissue parameter, and
// synthetic massage captures of known webs.
#include "records_fit.h"
#include "telehand/server/store/store.h"

namespace telehand::records {

/// `r.session` is the capture `info` in `store`, fitted as a massage (FitRequest::technique).
int runFitMassage(const FitRequest& r, server::store::SessionStore& store,
                  const server::store::SessionInfo& info);
/// A synthetic massage capture of the case's web (its [tissue], or tissueCase(name)).
int runSynthMassage(const SynthRequest& r);

}  // namespace telehand::records
