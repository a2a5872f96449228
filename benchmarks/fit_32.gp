# Drawn by flamerig (pipeline/plot.h). Redraw after an edit: gnuplot fit_32.gp
if (!exists('png_out')) png_out = 'fit_32.png'
if (!exists('svg_out')) svg_out = 'fit_32.svg'
set title '32^3, two 320x240 views: mean Delta E against time'
set xlabel 'time (s, log scale)'
set ylabel 'mean Delta E of the fitted views (CIELab)'
set key below horizontal maxrows 4
set grid xtics ytics lc rgb '#dddddd'
set border 3 lw 1
set tics nomirror
set logscale x 10
set yrange [0:*]
set y2range [0:*]
set linetype 1 lc rgb '#1f77b4' lw 2 pt 7 ps 0.5 dt 1
set linetype 2 lc rgb '#ff7f0e' lw 2 pt 7 ps 0.5 dt 1
do for [term = 1:2] {
  if (term == 1) { set terminal pngcairo size 900,480 font 'Sans,11' noenhanced; set output png_out }
  if (term == 2) { set terminal svg size 900,480 font 'Sans,11' noenhanced; set output svg_out }
  plot 'fit_32.dat' index 0 using 1:2 with linespoints lt 1 title 'paper Algorithm 2', \
       'fit_32.dat' index 1 using 1:2 with linespoints lt 2 title 'fast fit'
  unset output
}
