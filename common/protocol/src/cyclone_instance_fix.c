// Cyclone DDS 0.10 keeps one reference to an instance's key-to-instance map entry (its
// ddsi_tkmap_instance: the key and a serialized sample's buffer, about 0.5 kB) for every
// writer history that indexed the instance, and never drops it: not when the writer
// unregisters the instance, not when the writer is deleted (dds_whc.c,
// free_one_instance_from_idx; fixed upstream in 11.0 by "Fix tkmap_instance leak in WHC").
// A server that opens and retires sessions keyed by session id would keep every session's
// entry forever. telehand_dds_release_unregistered drops that one reference after the
// instance was unregistered.
#include "cyclone_instance_fix.h"

#include <dds/version.h>

#if DDS_VERSION_MAJOR == 0 && DDS_VERSION_MINOR == 10
#include <dds/ddsi/ddsi_domaingv.h>
#include <dds/ddsi/ddsi_tkmap.h>
#include <dds/ddsi/q_thread.h>

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
#else
int telehand_dds_release_unregistered(dds_instance_handle_t instance) {
  (void)instance;
  return 0;
}
#endif
