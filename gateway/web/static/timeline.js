// tactile-gateway live page: timeline (filled in by issue 35).
"use strict";
