/* References from TRAJECTORY records (docs/control-laws.md § References). */
#ifndef LAB_REFERENCE_H
#define LAB_REFERENCE_H
#include "description.h"

/* (r, r', r'', r''') of one trajectory at tick k (t = k / fs). */
void lab_reference(const lab_traj *t, uint32_t k, double fs, lab_real r[4]);

#endif
