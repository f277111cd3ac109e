/* bindgen input: the Embree API of the major version found, plus the spinedrr shim. */
#include "shim/spd_shim.h"
