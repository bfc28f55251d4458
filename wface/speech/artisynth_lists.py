"""Element lists vendored from ArtiSynth Models (artisynth_models, ``src/artisynth/models/face``, commit bcda205):
they are not in the face data folder.

- ``OOP_RING_ELEMENTS``: the ten OOP rings of ``BadinFaceDemoLipOpening``, ``geometry/oop/<ring>_elements.txt``, by
  ANSYS element number (the 14th column of the ``badinface_oop_csa_midsagittal`` .elem file).
- ``OOML_EXCITER_TARGETS``: the targets of the demo's ``OOMl`` exciter (``exciters/OOMl.art``, "b/5/e/N": bundle
  5, OOM, of ``BADIN_MUSCLES``; element descriptor N), as 0-based positions in the OOM bundle's element list. That
  list is ``MuscleBundle.addElementsNearFibres``' (every element within 6 mm of a fibre, in the mesh's order), so
  position N is the (N+1)-th OOM element by element number: 232 of OOM's 704, its part in the lower lip.

ArtiSynth Models licence (applies to every list in this module): Copyright (c) 2014, contributing Authors
and Organizations as indicated in subpackage COPYRIGHT notices. All rights reserved. Redistribution
and use of the ArtiSynth Models package in source and binary forms, with or without modification,
are permitted provided that the following conditions are met: 1. Redistributions of source code and
data must retain all copyright notices, this list of conditions and the following disclaimer.
2. Redistributions in binary form must reproduce all copyright notices, this list of conditions and
the following disclaimer in the documentation and/or other materials provided with the distribution.
3. Academic publication of work based on these models provides appropriate citations to the original
work, as indicated on the ArtiSynth Models download site. THIS SOFTWARE AND DATA IS PROVIDED BY THE
COPYRIGHT HOLDERS AND CONTRIBUTORS "AS IS" AND ANY EXPRESS OR IMPLIED WARRANTIES, INCLUDING, BUT NOT
LIMITED TO, THE IMPLIED WARRANTIES OF MERCHANTABILITY AND FITNESS FOR A PARTICULAR PURPOSE ARE
DISCLAIMED. IN NO EVENT SHALL THE COPYRIGHT HOLDER OR CONTRIBUTORS BE LIABLE FOR ANY DIRECT, INDIRECT,
INCIDENTAL, SPECIAL, EXEMPLARY, OR CONSEQUENTIAL DAMAGES (INCLUDING, BUT NOT LIMITED TO, PROCUREMENT OF
SUBSTITUTE GOODS OR SERVICES; LOSS OF USE, DATA, OR PROFITS; OR BUSINESS INTERRUPTION) HOWEVER CAUSED
AND ON ANY THEORY OF LIABILITY, WHETHER IN CONTRACT, STRICT LIABILITY, OR TORT (INCLUDING NEGLIGENCE OR
OTHERWISE) ARISING IN ANY WAY OUT OF THE USE OF THIS SOFTWARE, EVEN IF ADVISED OF THE POSSIBILITY OF
SUCH DAMAGE. Cite Nazari et al. 2010 and the ArtiSynth face papers (Stavness et al.).
"""

__all__ = ["OOML_EXCITER_TARGETS", "OOP_RING_ELEMENTS"]

_RINGS_TEXT = {
    "5Du": (
        "5337 5351 5352 5353 5354 5355 5356 5357 5358 5359 5360 5361 5362 5363 2192 2191 2190 2189 2188 2187 "
        "2186 2185 2184 2183 2182 2181 2180 2166"
    ),
    "6Sl": (
        "3047 889 838 837 836 835 824 823 505 506 507 908 909 508 3679 4080 4079 3678 3677 3676 3994 3995 "
        "4006 4007 4008 4009 4060 6218"
    ),
    "6M": (
        "2111 2112 2113 2114 2115 2116 2117 2118 2119 2120 2121 2122 2123 2124 2125 3120 2140 2141 2142 2143 "
        "2144 2145 2146 2147 2148 2149 2150 2151 2152 5323 5322 5321 5320 5319 5318 5317 5316 5315 5314 5313 "
        "5312 5311 6291 5296 5295 5294 5293 5292 5291 5290 5289 5288 5287 5286 5285 5284 5283 5282"
    ),
    "6Du": (
        "4762 4763 4078 4077 4076 4075 4074 4068 4067 4066 4065 4064 4063 4062 4061 890 891 892 893 894 895 "
        "896 897 903 904 905 906 907 1592 1591"
    ),
    "7Sl": (
        "3049 524 121 831 830 834 826 825 122 123 124 910 911 125 3296 4082 4081 3295 3294 3293 3996 3997 "
        "4005 4001 4002 3292 3695 6220"
    ),
    "7M": (
        "2218 2217 2216 2215 2214 2213 2212 2211 2210 3125 2209 3124 2208 2207 2206 3123 2138 2126 2127 2128 "
        "2129 2130 2131 2132 2133 2134 2135 2136 2137 5308 5307 5306 5305 5304 5303 5302 5301 5300 5299 5298 "
        "5297 5309 6294 5377 5378 5379 6295 5380 6296 5381 5382 5383 5384 5385 5386 5387 5388 5389"
    ),
    "7Du": (
        "6248 4765 4766 4767 6249 4768 6250 4769 3807 3809 3311 3312 3817 3313 3314 3854 683 143 142 646 141 "
        "140 638 636 1598 3079 1597 3078 1596 1595 1594 3077"
    ),
    "8Su": (
        "4605 6264 6263 4604 4477 3522 4472 4463 4462 4460 4410 4409 4408 4407 4828 1657 1236 1237 1238 1239 "
        "1289 1291 1292 1301 351 1306 1433 3092 3093 1434"
    ),
    "8Mu": (
        "5398 6302 6303 5399 5400 5401 5402 5403 5404 5405 5406 5407 5408 5409 5410 2239 2238 2237 2236 2235 "
        "2234 2233 2232 2231 2230 2229 2228 3132 3131 2227"
    ),
    "8Du": (
        "1656 1610 1609 1608 4770 6265 6266 4771 4772 4773 4774 4775 4776 4777 4778 4779 4780 4781 4827 1607 "
        "1606 1605 1604 1603 1602 1601 1600 3095 3094 1599"
    ),
}
OOP_RING_ELEMENTS: dict[str, tuple[int, ...]] = {k: tuple(int(v) for v in s.split()) for k, s in _RINGS_TEXT.items()}

OOML_EXCITER_TARGETS: tuple[int, ...] = tuple(
    int(v)
    for v in (
        "7 8 9 10 11 12 13 14 15 23 24 25 26 27 28 29 30 39 40 41 42 52 53 54 55 56 57 58 59 79 80 81 83 84 85 88 90 "
        "91 92 93 94 95 100 103 104 105 106 107 108 109 110 111 197 198 199 200 201 202 203 204 205 206 207 208 209 "
        "210 211 212 237 238 239 240 241 242 243 244 245 246 247 248 249 250 251 252 253 254 255 256 257 258 259 260 "
        "261 262 263 264 265 266 267 268 269 270 271 272 273 274 275 302 303 304 305 328 329 330 331 332 359 360 361 "
        "362 363 364 365 366 367 375 376 377 378 379 380 381 382 391 392 393 394 404 405 406 407 408 409 410 411 431 "
        "432 433 435 436 437 440 442 443 444 445 446 447 452 455 456 457 458 459 460 461 462 463 549 550 551 552 553 "
        "554 555 556 557 558 559 560 561 562 563 564 589 590 591 592 593 594 595 596 597 598 599 600 601 602 603 604 "
        "605 606 607 608 609 610 611 612 613 614 615 616 617 618 619 620 621 622 623 624 625 626 627 654 655 656 657 "
        "680 681 682 683 684"
    ).split()
)
