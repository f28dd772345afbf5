// Cyclone DDS 0.10 keeps one reference to an instance's key-to-instance map entry (its
// ddsi_tkmap_instance: the key and a serialized sample's buffer, about 0.5 kB) for every
// writer history that indexed the instance, and never drops it: not when the writer
// unregisters the instance, not when the writer is deleted (dds_whc.c,
// free_one_instance_from_idx; fixed upstream in 11.0 by "Fix tkmap_instance leak in WHC").
// A server that opens and retires sessions keyed by session id would keep every session's
// entry forever. telehand_dds_release_unregistered drops that one reference after the
// instance was unregistered.
//
// Cyclone DDS 0.10 also keeps freed samples (serialized, up to 256 bytes) on a pool per
// domain for reuse, up to 8,192 of them (ddsi_serdata_default.c), and never gives them back
// while the domain lives. Its level follows the most samples held at once: a burst of 10,000
// OPENs fills it, and the pooled samples, spread over the pages of the threads that received
// or wrote them, keep those pages resident. telehand_dds_release_pooled_samples frees them.
#include "cyclone_instance_fix.h"

#include <dds/version.h>

#if DDS_VERSION_MAJOR == 0 && DDS_VERSION_MINOR == 10
#include <dds/ddsi/ddsi_domaingv.h>
#include <dds/ddsi/ddsi_serdata_default.h>
#include <dds/ddsi/ddsi_tkmap.h>
#include <dds/ddsi/q_freelist.h>
#include <dds/ddsi/q_thread.h>
#include <dds/ddsrt/heap.h>
#include <dds/ddsrt/sync.h>

int telehand_dds_release_unregistered(dds_instance_handle_t instance) {
  if (instance == DDS_HANDLE_NIL) return 0;
  // The domain this thread last called into (the unregister just before): Cyclone leaves it
  // in the thread's state; the map may be read only while the thread is marked awake.
  struct thread_state* ts = lookup_thread_state();
  struct ddsi_domaingv* gv = (struct ddsi_domaingv*)ddsrt_atomic_ldvoidp(&ts->gv);
  if (gv == NULL) return 0;
  thread_state_awake(ts, gv);
  struct ddsi_tkmap_instance* tk = ddsi_tkmap_find_by_id(gv->m_tkmap, instance);
  if (tk != NULL) {
    ddsi_tkmap_instance_unref(gv->m_tkmap, tk);  // the one the writer history kept
    ddsi_tkmap_instance_unref(gv->m_tkmap, tk);  // the one find_by_id took
  }
  thread_state_asleep(ts);
  return tk != NULL;
}

#if FREELIST_TYPE == FREELIST_DOUBLE
int telehand_dds_release_pooled_samples(void) {
  struct thread_state* ts = lookup_thread_state();
  struct ddsi_domaingv* gv = (struct ddsi_domaingv*)ddsrt_atomic_ldvoidp(&ts->gv);
  if (gv == NULL || gv->serpool == NULL) return 0;
  struct nn_freelist* fl = &gv->serpool->freelist;
  // The pool (q_freelist.c, FREELIST_DOUBLE): NN_FREELIST_NPAR magazines in use, each under
  // its own lock, and the full and empty magazines under the pool's lock, which is taken
  // while holding a magazine's (the order Cyclone's push and pop take them in). The samples
  // are taken out under the locks and freed after, as the pool frees them (dds_free).
  int n = 0;
  struct nn_freelistM* full = NULL;
  struct nn_freelistM* empty = NULL;
  for (int k = 0; k < NN_FREELIST_NPAR; k++) {
    void* xs[NN_FREELIST_MAGSIZE];
    ddsrt_mutex_lock(&fl->inner[k].lock);
    const uint32_t count = fl->inner[k].count;
    for (uint32_t j = 0; j < count; j++) xs[j] = fl->inner[k].m->x[j];
    fl->inner[k].count = 0;
    if (k == 0) {
      ddsrt_mutex_lock(&fl->lock);
      full = fl->mlist;
      empty = fl->emlist;
      fl->mlist = NULL;
      fl->emlist = NULL;
      fl->count = 0;
      ddsrt_mutex_unlock(&fl->lock);
    }
    ddsrt_mutex_unlock(&fl->inner[k].lock);
    for (uint32_t j = 0; j < count; j++) dds_free(xs[j]);
    n += (int)count;
  }
  while (full != NULL) {
    struct nn_freelistM* m = full;
    full = (struct nn_freelistM*)m->next;
    for (uint32_t j = 0; j < NN_FREELIST_MAGSIZE; j++) dds_free(m->x[j]);
    n += NN_FREELIST_MAGSIZE;
    ddsrt_free(m);
  }
  while (empty != NULL) {
    struct nn_freelistM* m = empty;
    empty = (struct nn_freelistM*)m->next;
    ddsrt_free(m);
  }
  return n;
}
#else
int telehand_dds_release_pooled_samples(void) { return 0; }
#endif
#else
int telehand_dds_release_unregistered(dds_instance_handle_t instance) {
  (void)instance;
  return 0;
}
int telehand_dds_release_pooled_samples(void) { return 0; }
#endif
