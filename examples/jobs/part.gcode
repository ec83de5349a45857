; A part for the mill example: a 40 x 30 mm pocket outline with rounded
; corners and a drilled hole pattern, in a block whose top is at z = -60.
; Millimetres, absolute.
G21 G90
G0 Z-55          ; clear the stock
G0 X20 Y20       ; above the first corner
M3 S12000        ; spindle on; the machine waits for it to settle
G1 Z-61 F300     ; plunge 1 mm into the stock
G1 X55 F1200     ; bottom edge
G2 X60 Y25 I0 J5 ; rounded corner (5 mm radius)
G1 Y45
G3 X55 Y50 I-5 J0
G1 X25
G2 X20 Y45 I0 J-5
G1 Y25
G2 X25 Y20 I5 J0
G1 X55           ; close the outline
G0 Z-55
; three holes along the pocket's middle, each a 1.5 mm peck
G0 X30 Y35
G1 Z-61.5 F300
G4 P0.2          ; dwell at depth
G0 Z-55
G0 X40 Y35
G1 Z-61.5 F300
G4 P0.2
G0 Z-55
G0 X50 Y35
G1 Z-61.5 F300
G4 P0.2
G0 Z-55
M5               ; spindle off
G0 X0 Y0
M30
