#!/usr/bin/env bash
# Build ArtiSynth headless, offline, to run its BadinFaceDemoLipOpening with RunLipOpening.java.
#
# With network access the usual way is simpler: clone artisynth_core and artisynth_models, run the
# core's bin/updateArtisynthLibs (it downloads the jars and native libraries from artisynth.org) and
# compile; then CP=core/classes:core/lib/*:models/classes and NATIVE=core/lib/Linux64.
# This script does it without artisynth.org, as measured for README.md ("ArtiSynth itself, run
# headless"): Debian's Java packages for the jars Debian has, small stand-ins for the five jars the
# lip-opening demo never calls (argparser, quickhull3d, poly2tri, matlabcontrol, jline), and the three
# native libraries the demo needs built from the core's own C sources: PardisoJNI against Intel MKL
# from PyPI (mkl-devel), TetgenJNI (TetGen 1.5.1, for the muscle fibre directions) and RobustPreds.
#
#   CORE=artisynth_core MODELS=artisynth_models OUT=/tmp/artisynth bash build_headless.sh
#   (needs: openjdk-17-jdk-headless g++ and apt-get install libjogl2-java libgluegen2-rt-java jython
#    libcommons-vfs-java libjsoup-java libjgoodies-looks-java libslf4j-java libjsch-java; pip)
# Then (the Pardiso solves single-threaded, as measured):
#   ARTISYNTH_HOME=$OUT MKL_THREADING_LAYER=SEQUENTIAL java -Djava.awt.headless=true -Djava.library.path=$OUT/native -cp $OUT/run:$(cat $OUT/cp.txt) \
#       RunLipOpening nodes.txt 1.0 $MODELS/src/artisynth/models/face/data/approximant/oop.txt
# Measured here: artisynth_core b9aa17bb, artisynth_models bcda205, OpenJDK 17.0.15, MKL 2026.2.
set -euo pipefail
: "${CORE:?set CORE to an artisynth_core checkout}" "${MODELS:?set MODELS to an artisynth_models checkout}"
OUT=${OUT:-/tmp/artisynth}
HERE=$(cd "$(dirname "$0")" && pwd)
J=/usr/share/java
JH=$(dirname "$(dirname "$(readlink -f "$(command -v javac)")")")
mkdir -p "$OUT"/{core,models/classes,run,native,stubs,tmp}
CP="$CORE/lib/vfs2.jar:$CORE/lib/gpcj-2.2.0-full.jar:$J/jogl2.jar:$J/gluegen2-rt.jar:$J/jython.jar:$J/jsoup.jar"
CP="$CP:$J/looks.jar:$J/slf4j-api.jar:$J/jsch.jar"

# 1. stand-ins for jars that are not packaged and that the demo does not use
S=$OUT/stubs
mkdir -p "$S/argparser" "$S/quickhull3d" "$S/matlabcontrol" "$S/org/python/jline/console"
for h in Boolean:boolean:false Double:double:0 Int:int:0 String:String:null Float:float:0 Long:long:0 Char:char:0; do
  IFS=: read -r name type zero <<<"$h"
  echo "package argparser; public class ${name}Holder { public $type value = $zero;
    public ${name}Holder () {} public ${name}Holder ($type v) { value = v; } }" >"$S/argparser/${name}Holder.java"
done
cat >"$S/argparser/ArgParser.java" <<'EOF'
package argparser;
public class ArgParser {  // command-line parsing of ArtiSynth's Main, which a headless run does not start
   private String unmatched;
   public ArgParser (String s) {}
   public ArgParser (String s, boolean b) {}
   public void addOption (String spec, Object holder) {}
   public String[] matchAllArgs (String[] args) { return args; }
   public String[] matchAllArgs (String[] args, int idx, int flags) { return args; }
   public int matchArg (String[] args, int idx) { unmatched = args[idx]; return idx + 1; }
   public String getUnmatchedArgument () { String s = unmatched; unmatched = null; return s; }
   public String getOptionsMessage () { return ""; }
   public String getOptionsMessage (int n) { return ""; }
   public static String[] prependArgs (java.io.Reader r, String[] a) { return a; }
}
EOF
cat >"$S/quickhull3d/Point3d.java" <<'EOF'
package quickhull3d;
public class Point3d { public double x, y, z; public Point3d () {} public Point3d (double x, double y, double z) { this.x = x; this.y = y; this.z = z; } }
EOF
cat >"$S/quickhull3d/QuickHull3D.java" <<'EOF'
package quickhull3d;
// maspack.geometry.OBB catches this and fits its boxes to the points' covariance instead of their hull:
// the collision bounding boxes are looser, the contacts found are the same
public class QuickHull3D {
   public void build (double[] p, int n) { throw new UnsupportedOperationException ("no quickhull3d"); }
   public void build (Point3d[] p) { throw new UnsupportedOperationException ("no quickhull3d"); }
   public void triangulate () {}
   public Point3d[] getVertices () { return new Point3d[0]; }
   public int[][] getFaces () { return new int[0][]; }
}
EOF
for c in MatlabInvocationException MatlabConnectionException; do
  echo "package matlabcontrol; public class $c extends Exception { public $c (String s) { super (s); } }" >"$S/matlabcontrol/$c.java"
done
echo "package org.python.jline.console; public class UserInterruptException extends RuntimeException {
  public UserInterruptException (String s) { super (s); } }" >"$S/org/python/jline/console/UserInterruptException.java"

# 2. the core's sources, less what needs the missing jars (apps, tests, DICOM via GDCM, movies via JMF)
rm -rf "$OUT/src" && cp -r "$CORE/src" "$OUT/src" && cd "$OUT/src"
rm -rf artisynth/demos maspack/apps artisynth/models/tgcs2025  # tgcs2025 (newer cores) imports the demos
rm -f maspack/solvers/LemkeContactSolverTest.java \
  maspack/fileutil/FileManagerExamples.java maspack/image/dicom/DicomImageDecoderGDCM.java \
  maspack/geometry/DelaunayTriangulatorTest.java artisynth/core/moviemaker/MakeMovieFromData.java \
  artisynth/core/moviemaker/Merge.java maspack/ipopt/JipoptExample.java maspack/ipopt/JipoptTest.java \
  artisynth/core/driver/RootModelManagerTest.java artisynth/core/modeltest/TransformGeometryTest.java \
  artisynth/core/modeltest/AttachmentTest.java artisynth/core/workspace/FemModelDeformer.java
sed -i 's/^\( *imageDecoders.add(new DicomImageDecoderGDCM()\)/\/\/\1/' maspack/image/dicom/DicomReader.java
sed -i '/MakeMovieFromData movieFromData = new MakeMovieFromData();/,/fn+".mov", this);/s/^/\/\/ /' \
  artisynth/core/moviemaker/MovieMaker.java
sed -i 's/^\( *\)new Merge (args);/\1\/\/ new Merge (args);/' artisynth/core/moviemaker/MovieMakerDialog.java
sed -i 's/^import matlabcontrol\.\*;/import matlabcontrol.MatlabInvocationException; import matlabcontrol.MatlabConnectionException;/' \
  artisynth/core/util/MatlabInterfaceException.java
cat >artisynth/core/util/MatlabInterface.java <<'EOF'
package artisynth.core.util;
public class MatlabInterface {  // no MATLAB here
   public static MatlabInterface create () throws MatlabInterfaceException { throw new MatlabInterfaceException ("no matlab"); }
   public static MatlabInterface create (double t) throws MatlabInterfaceException { throw new MatlabInterfaceException ("no matlab"); }
   public boolean isConnected () { return false; }
   public void dispose () {}
   public void objectToMatlab (Object o, String n) throws MatlabInterfaceException { throw new MatlabInterfaceException ("no matlab"); }
   public double[][] arrayFromMatlab (String n) throws MatlabInterfaceException { throw new MatlabInterfaceException ("no matlab"); }
}
EOF
cat >maspack/geometry/DelaunayTriangulator.java <<'EOF'
package maspack.geometry;
import java.util.List;
import maspack.matrix.Vector2d;
public class DelaunayTriangulator {  // poly2tri is not packaged; the demo triangulates nothing in 2D
   public static class Triangle {
      public Triangle getAdjacentTriangle (int vi) { return null; }
      public int getAdjacentTriangleIndex (int vi) { return -1; }
      public Vector2d getPoint (int vi) { return null; }
      public int getPointIndex (int vi) { return -1; }
      public int getIndex () { return -1; }
   }
   public static List<Triangle> triangulate (List<? extends Vector2d> p) { throw new UnsupportedOperationException ("no poly2tri"); }
   public static List<Triangle> triangulate (List<? extends Vector2d> p, int[] c) { throw new UnsupportedOperationException ("no poly2tri"); }
}
EOF
find . "$S" -name '*.java' >"$OUT/core_sources.txt"
javac -nowarn -encoding UTF-8 -J-Xmx4g -cp "$CP" -d "$OUT/core" @"$OUT/core_sources.txt"

# 3. the demo and what it uses, from artisynth_models
javac -nowarn -encoding UTF-8 -cp "$OUT/core:$CP" -sourcepath "$MODELS/src" -d "$OUT/models/classes" \
  "$MODELS/src/artisynth/models/face/BadinFaceDemoLipOpening.java"
echo "$OUT/models/classes:$OUT/core:$CP" >"$OUT/cp.txt"
# ArtisynthPath finds the demo's geometry files in the src/ folder beside its classes/ folder
ln -sfn "$MODELS/src" "$OUT/models/src"

# 4. native libraries from the core's C sources
python3 -m venv "$OUT/mkl" && "$OUT/mkl/bin/pip" install -q mkl-devel
L=$CORE/src/maspack/solvers/lib
g++ -O2 -shared -fPIC "$L/PardisoMklJNI.cc" "$L/pardisoMkl.cc" -I"$JH/include" -I"$JH/include/linux" -I"$OUT/mkl/include" \
  -I"$L" -L"$OUT/mkl/lib" -l:libmkl_rt.so.3 -liomp5 -Wl,-rpath,"$OUT/mkl/lib" -o "$OUT/native/libPardisoJNI.so.2021.1.1"
G=$CORE/src/maspack/geometry/lib
javac -h "$OUT/native" -d "$OUT/tmp" -cp "$OUT/core" "$OUT/src/maspack/geometry/RobustPreds.java" \
  "$OUT/src/maspack/geometry/TetgenTessellator.java" 2>/dev/null
gcc -O0 -fPIC -DLINUX -c "$G/predicatesC.c" -I"$G" -o "$OUT/tmp/predicatesC.o"
gcc -O2 -fPIC -shared -DLINUX -I"$JH/include" -I"$JH/include/linux" -I"$G" -I"$OUT/native" "$G/RobustPredsJNI.c" \
  "$G/geoPred.c" "$G/geoPredShewchuck.c" "$OUT/tmp/predicatesC.o" -lm -o "$OUT/native/libRobustPreds.so.1.1"
g++ -O0 -fPIC -DTETLIBRARY -c "$G/tetgen1.5.1/predicates.cxx" -o "$OUT/tmp/predicates.o"
g++ -O2 -fPIC -shared -DTETLIBRARY -I"$G" -I"$G/tetgen1.5.1" -I"$JH/include" -I"$JH/include/linux" -I"$OUT/native" \
  "$G/tetgenJNI.cc" "$G/tetgen1.5.1/tetgen.cxx" "$OUT/tmp/predicates.o" -o "$OUT/native/libTetgenJNI.so.1.5.1.1"

# 5. the driver
javac -nowarn -cp "$(cat "$OUT/cp.txt")" -d "$OUT/run" "$HERE/RunLipOpening.java"
echo "built: run with ARTISYNTH_HOME=$OUT MKL_THREADING_LAYER=SEQUENTIAL java -Djava.awt.headless=true -Djava.library.path=$OUT/native -cp $OUT/run:\$(cat $OUT/cp.txt) RunLipOpening ..."
