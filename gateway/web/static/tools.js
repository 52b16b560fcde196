// tactile-gateway live page: tools (filled in by issue 35).
"use strict";
